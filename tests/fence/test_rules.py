"""Zone rules: debounce, approach, dwell, work areas, lost people."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from stereopose.fence import FenceMonitor, Site, Zone
from stereopose.skeleton import joint_index
from stereopose.types import People3D

FPS = 25.0
WRIST = joint_index("right_wrist")
PANEL = [[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]]


def body(x: float, y: float = 0.5, wrist_x: float | None = None) -> np.ndarray:
    """A standing person centred at (x, y) with the right wrist reaching to wrist_x."""
    J = np.zeros((17, 3))
    J[:, 0], J[:, 1] = x + np.linspace(-0.1, 0.1, 17), y
    J[:, 2] = np.linspace(1.7, 0.05, 17)
    if wrist_x is not None:
        J[WRIST] = [wrist_x, y, 1.2]
    return J


def frame(f: int, *people: tuple[int, np.ndarray]) -> People3D:
    P = len(people)
    joints = np.array([j for _, j in people]).reshape(P, 17, 3)
    return People3D(
        f,
        joints,
        np.ones((P, 17)),
        np.array([i for i, _ in people], dtype=np.int64),
        np.zeros((P, 17)),
        np.full((P, 17), 3),
        np.full((P, 4), -1),
    )


def monitor(**zone) -> FenceMonitor:
    kw = dict(name="panel", kind="energized", polygon=np.array(PANEL), z=(0.0, 2.0))
    kw.update(zone)
    return FenceMonitor(Site((Zone(**kw),)), FPS)


def run(mon: FenceMonitor, xs: list[float], person: int = 1, **body_kw):
    """Events per frame for a person whose body is at x = xs[f] (None: not seen)."""
    out = []
    for f, x in enumerate(xs):
        people = frame(f) if x is None else frame(f, (person, body(x, **body_kw)))
        out.append(mon.update(people))
    return out


def flat(events_per_frame):
    return [(f, e.type) for f, evs in enumerate(events_per_frame) for e in evs]


@pytest.mark.parametrize("flicker", [1, 2])
def test_a_short_flicker_opens_nothing(flicker: int) -> None:
    xs = [3.0] * 10 + [0.5] * flicker + [3.0] * 20
    assert flat(run(monitor(), xs)) == []


def test_entry_is_reported_after_the_debounce_with_its_onset() -> None:
    xs = [3.0] * 10 + [0.5] * 30
    events = run(monitor(), xs)
    assert flat(events) == [(12, "enter")]  # 3 frames inside: 0.08 s
    e = events[12][0]
    assert e.onset_t == pytest.approx(10 / FPS) and e.t - e.onset_t <= 0.5
    assert e.person == 1 and e.zone == "panel" and e.kind == "energized" and e.joint
    assert e.position == pytest.approx((0.5, 0.5), abs=0.1)  # the mid-hip point


def test_exit_ignores_a_one_frame_gap_and_reports_the_stay() -> None:
    xs = [0.5] * 20 + [3.0] + [0.5] * 10 + [3.0] * 20
    events = run(monitor(), xs)
    assert flat(events) == [(2, "enter"), (31 + 5, "exit")]  # out for exit_s = 0.2 s
    e = events[36][0]
    assert e.onset_t == pytest.approx(31 / FPS)
    assert e.duration_s == pytest.approx(31 / FPS)


def test_a_hand_approaching_an_energized_zone() -> None:
    mon = monitor(margin_m=0.5, joints=(WRIST,))
    # the body stands 1 m from the panel; the hand reaches to 0.3 m, then into it
    events = run(mon, [2.0] * 10, wrist_x=1.3)
    assert flat(events) == [(2, "approach")]
    e = events[2][0]
    assert e.joint == "right_wrist" and e.distance_m == pytest.approx(0.3)
    events = run(mon, [2.0] * 5, wrist_x=0.8)
    assert [e.type for evs in events for e in evs] == ["enter"]


def test_non_triggering_joints_do_not_enter() -> None:
    mon = monitor(joints=(WRIST,))
    assert flat(run(mon, [0.5] * 10, wrist_x=3.0)) == []
    assert flat(run(monitor(), [0.5] * 10, wrist_x=3.0)) == [(2, "enter")]


def test_dwell_once_per_visit_and_allowed_people() -> None:
    mon = monitor(dwell_s=1.0, allowed=frozenset({1}))
    events = run(mon, [0.5] * 60 + [3.0] * 10 + [0.5] * 40)
    types = flat(events)
    assert [t for _, t in types] == ["enter", "dwell", "exit", "enter", "dwell"]
    assert types[1][0] == 25  # 1 s after the onset at frame 0
    assert all(e.allowed for evs in events for e in evs)


def test_leaving_a_work_area_for_an_expected_person() -> None:
    mon = monitor(kind="work_area", expected=frozenset({1}))
    types = [t for _, t in flat(run(mon, [0.5] * 10 + [3.0] * 10))]
    assert types == ["enter", "exit", "left_work_area"]
    mon = monitor(kind="work_area", expected=frozenset({1}))
    types = [t for _, t in flat(run(mon, [0.5] * 10 + [3.0] * 10, person=2))]
    assert types == ["enter", "exit"]


def test_a_person_lost_inside_exits_once_the_track_is_gone() -> None:
    mon = monitor()
    events = run(mon, [0.5] * 10 + [None] * 80)
    types = flat(events)
    assert types[0] == (2, "enter") and types[1][1] == "exit"
    e = [e for evs in events for e in evs][1]
    assert e.lost and e.t - 9 / FPS > mon.lost_s
    assert len(types) == 2


def test_people_are_independent_and_nobody_is_fine() -> None:
    mon = monitor()
    evs = []
    for f in range(10):
        evs += mon.update(frame(f, (1, body(0.5)), (2, body(3.0))))
    for f in range(10, 20):
        evs += mon.update(frame(f))
    assert [(e.person, e.type) for e in evs] == [(1, "enter")]


def predicted(people: People3D) -> People3D:
    """The same people, every one of them only predicted by the tracker (no camera saw them)."""
    return dataclasses.replace(people, predicted=np.ones(len(people), dtype=bool))


def test_a_predicted_position_alone_raises_no_alarm() -> None:
    """The tracker carries a person nobody sees along his last velocity: carried into the
    zone, he raises no enter nor approach; seen there, he does."""
    mon = monitor(margin_m=0.5)
    out = [mon.update(frame(f, (1, body(3.0)))) for f in range(5)]
    out += [mon.update(predicted(frame(f, (1, body(0.5))))) for f in range(5, 40)]
    assert flat(out) == []
    out += [mon.update(frame(f, (1, body(0.5)))) for f in range(40, 50)]
    assert flat(out) == [(42, "enter")]


def test_a_person_inside_stays_inside_while_only_predicted_and_is_lost_in_time() -> None:
    """Missed by every camera while inside: no exit while the track carries him (even carried
    outside), he is inside again when seen there; carried for longer than lost_s after he was
    last seen, he exits as lost, timed from that last sight."""
    mon = monitor()
    out = [mon.update(frame(f, (1, body(0.5)))) for f in range(10)]
    out += [mon.update(predicted(frame(f, (1, body(3.0))))) for f in range(10, 30)]
    out += [mon.update(frame(f, (1, body(0.5)))) for f in range(30, 40)]
    assert flat(out) == [(2, "enter")]
    last_seen = 39 / FPS
    f = 40
    while not out[-1]:
        out.append(mon.update(predicted(frame(f, (1, body(0.5))))))
        f += 1
    (e,) = out[-1]
    assert e.type == "exit" and e.lost and e.onset_t == pytest.approx(last_seen)
    assert e.t - last_seen == pytest.approx(mon.lost_s, abs=1.5 / FPS)


def test_a_zone_switched_off_raises_nothing_and_stays_off_across_a_site_change() -> None:
    mon = monitor()
    assert flat(run(mon, [0.5] * 10)) == [(2, "enter")]
    assert mon.switch("panel", False) and not mon.switch("panel", False)
    assert not mon.switch("no such zone", False)
    assert mon.occupants("panel") == ([], [])
    assert flat(run(mon, [3.0] * 10 + [0.5] * 10)) == []
    again = monitor()  # the same site taken again (a site change): the switch kept
    again.carry(mon)
    assert flat(run(again, [0.5] * 10)) == []
    assert again.switch("panel", True)
    assert flat(run(again, [0.5] * 10)) == [(2, "enter")]
