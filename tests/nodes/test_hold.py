"""The fusion service's holds for the nodes' carried steps: what it says at each step (the
cameras that see someone near an energized zone, every camera while nobody's place is known,
none without hazards), read back by a node for as long as it stands, and any other message
counted and ignored; with no fresh hold a node holds every camera."""

from __future__ import annotations

import json

import numpy as np
import pytest

from stereopose.nodes.hold import VALID_S, HoldTeller, HoldWatch, decode_hold, encode_hold
from stereopose.nodes.wire import WireError
from stereopose.sim.scene import make_rig
from stereopose.types import People3D
from stereopose.zones import Zone
from stereopose.zones.hazard import Hazards

NAMES = ["cam01", "cam02", "cam03"]  # make_rig's names
RIG = make_rig(3, np.random.default_rng(4))  # around a 12 x 8 m room, looking at its centre
BUSBAR = Zone(
    "busbar",
    "energized",
    np.array([[5.5, 3.5], [6.5, 3.5], [6.5, 4.5], [5.5, 4.5]]),
    (1.5, 2.5),
    margin_m=0.3,
)


class _Clock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def test_a_node_with_no_fresh_hold_holds_every_camera():
    clock = _Clock()
    watch = HoldWatch(clock)
    assert watch.held(NAMES) == set(NAMES)  # nothing heard yet: never carried
    assert watch.take(encode_hold(1.0, ["cam02"], False))
    assert watch.held(NAMES) == {"cam02"}
    clock.now += VALID_S + 0.01  # the fusion service silent since: stale
    assert watch.held(NAMES) == set(NAMES)
    assert watch.take(encode_hold(2.0, [], True))  # nobody's place known yet: all
    assert watch.held(NAMES) == set(NAMES)
    assert watch.take(encode_hold(3.0, [], False))
    assert watch.held(NAMES) == set()
    assert watch.figures() == {"taken": 3, "malformed": 0}


@pytest.mark.parametrize(
    "payload",
    [
        b"",
        b"\xff\xfe",
        b"[]",
        b'{"v": 2, "all": false, "held": [], "valid_s": 0.5}',
        b'{"v": 1, "all": "no", "held": [], "valid_s": 0.5}',
        b'{"v": 1, "all": false, "held": "c1", "valid_s": 0.5}',
        b'{"v": 1, "all": false, "held": [1], "valid_s": 0.5}',
        b'{"v": 1, "all": false, "held": [], "valid_s": true}',
        b'{"v": 1, "all": false, "held": [], "valid_s": 1e309}',
        b'{"v": 1, "all": false, "held": [], "valid_s": 3600}',
        json.dumps({"v": 1, "all": False, "held": ["c"] * 300, "valid_s": 0.5}).encode(),
        b"{" * 100_000,
    ],
)
def test_any_other_message_is_counted_and_changes_nothing(payload):
    watch = HoldWatch(_Clock())
    watch.take(encode_hold(1.0, [], False))
    assert not watch.take(payload)
    assert watch.held(NAMES) == set() and watch.figures() == {"taken": 1, "malformed": 1}
    with pytest.raises(WireError):
        decode_hold(payload)


def _people(x: float, y: float) -> People3D:
    """One person standing at (x, y), his joints on a line from the floor up to 1.7 m."""
    joints = np.zeros((1, 17, 3))
    joints[0] = np.column_stack([np.full(17, x), np.full(17, y), np.linspace(1.7, 0.0, 17)])
    return People3D(
        frame=0,
        joints=joints,
        conf=np.ones((1, 17)),
        ids=np.array([1]),
        reprojection_px=np.zeros((1, 17)),
        views=np.full((1, 17), 3),
        detections=np.full((1, 3), -1),
    )


def test_the_fusion_service_tells_the_cameras_that_see_someone_near_a_live_zone():
    sent: list[tuple[str, bytes]] = []
    teller = HoldTeller(lambda topic, payload: sent.append((topic, payload)), "s/n/hold", RIG, 10)
    teller.tell(_people(6.0, 4.0), 1_000.0)  # no hazards: nothing held
    assert decode_hold(sent[-1][1])[:2] == (False, frozenset())
    teller.set_hazards(Hazards([BUSBAR]))
    teller.tell(None, 1_000.0)  # hazards and nobody's place known: every camera
    assert decode_hold(sent[-1][1])[0] is True
    teller.tell(_people(6.0, 4.0), 1_000.0)  # his head at the busbar: the cameras seeing him
    all_, held, valid = decode_hold(sent[-1][1])
    assert not all_ and held == set(NAMES) and valid == VALID_S
    teller.tell(_people(1.0, 1.0), 1_000.0)  # in a far corner: nothing held
    assert decode_hold(sent[-1][1])[1] == frozenset()
    assert teller.told == 4 and teller.failed == 0 and {t for t, _ in sent} == {"s/n/hold"}


def test_a_broker_gone_is_counted_never_raised():
    def refuse(topic, payload):
        raise RuntimeError("the client is closing")

    teller = HoldTeller(refuse, "s/n/hold", RIG, 10)
    teller.tell(None, 0.0)
    assert teller.failed == 1 and teller.told == 0
