"""The carried steps' rule near hazards for cameras detected at nodes.

A node carries a camera's step as `run` and `serve` do (detection.carry), but it has no 3D:
the fusion service, which tracks the people, tells it which cameras see someone near an
energized zone (pipeline.track_regions.held_cameras), on the hold topic at each step
(nodes.wire). A hold is good for `valid_s` after it came; with none fresh (the fusion service
away, the broker down, a node just started) every camera of the node is held: a node never
carries a step it was not told it may.

    teller = HoldTeller(publish, topics.hold, rig, fps)   # the fusion service
    teller.set_hazards(hazards)                           # and at each new site
    teller.tell(people, start_epoch)                      # each step
    watch = HoldWatch()                       # a node
    watch.take(payload)                       # each hold message
    held = watch.held(names)                  # the cameras it must detect now
"""

from __future__ import annotations

import json
import math
import threading
import time
from collections.abc import Callable, Collection

from stereopose.nodes.wire import VERSION, WireError
from stereopose.pipeline.track_regions import held_cameras
from stereopose.types import People3D, Rig
from stereopose.zones.hazard import Hazards

MAX_PAYLOAD = 64 * 1024  # bytes of a hold message
MAX_HELD = 256  # cameras named in one
VALID_S = 0.5  # a hold stands this long after it came: several steps, a broker's hiccup


def encode_hold(t: float, held: Collection[str], all_: bool, valid_s: float = VALID_S) -> bytes:
    """The hold message of the step at capture time t (seconds since 1970)."""
    doc = {"v": VERSION, "t": round(float(t), 3), "valid_s": float(valid_s), "all": bool(all_)}
    doc["held"] = sorted(str(n) for n in held)[:MAX_HELD]
    return json.dumps(doc, separators=(",", ":")).encode()


def decode_hold(payload: bytes) -> tuple[bool, frozenset[str], float]:
    """(all cameras held, the cameras held, valid_s) of a hold message; a WireError naming
    the problem for anything else."""
    if len(payload) > MAX_PAYLOAD:
        raise WireError(f"hold message of {len(payload)} bytes (at most {MAX_PAYLOAD})")
    try:
        doc = json.loads(payload)
    except (ValueError, UnicodeDecodeError) as e:
        raise WireError(f"hold message is not JSON: {e}") from None
    if not isinstance(doc, dict) or doc.get("v") != VERSION:
        raise WireError("hold message: not a version 1 object")
    all_, held, valid = doc.get("all"), doc.get("held"), doc.get("valid_s")
    if not isinstance(all_, bool):
        raise WireError("hold message: 'all' is not true or false")
    if not isinstance(held, list) or len(held) > MAX_HELD:
        raise WireError(f"hold message: 'held' is not a list of at most {MAX_HELD} cameras")
    if not all(isinstance(n, str) for n in held):
        raise WireError("hold message: 'held' names a camera by something else than text")
    if (
        isinstance(valid, bool)
        or not isinstance(valid, int | float)
        or not math.isfinite(valid)
        or not 0 < valid <= 60
    ):
        raise WireError("hold message: 'valid_s' is not a number of seconds in (0, 60]")
    return all_, frozenset(held), float(valid)


class HoldTeller:
    """The fusion service's side: at each step, the cameras of `rig` that see someone near
    one of `hazards` (set_hazards; none: nothing is held) published with
    `publish(topic, payload)`, QoS 0; every camera while nobody's place is known yet. A
    failure to publish is counted, never raised: the nodes then hold every camera by
    themselves once the last hold is stale."""

    def __init__(
        self, publish: Callable[[str, bytes], object], topic: str, rig: Rig, fps: float
    ) -> None:
        self.publish, self.topic, self.rig, self.fps = publish, topic, rig, float(fps)
        self.hazards: Hazards | None = None
        self.told = 0
        self.failed = 0

    def set_hazards(self, hazards: Hazards | None) -> None:
        """The hazards from the next step on (a new site while serving)."""
        self.hazards = hazards

    def tell(self, people: People3D | None, start_epoch: float) -> None:
        """The hold of the step whose tracked people are `people` (None: none known yet);
        start_epoch: the service's t = 0 in seconds since 1970."""
        names = list(self.rig.names)
        t = people.time(self.fps) if people is not None else 0.0
        # a hand may move on for as long as this hold stands at a node
        held = held_cameras(self.hazards, people, self.rig, names, t, self.fps, VALID_S)
        every = people is None and bool(self.hazards)
        try:
            self.publish(self.topic, encode_hold(start_epoch + t, held, every))
            self.told += 1
        except Exception:  # a broker gone, a client closing: the nodes hold everything
            self.failed += 1


class HoldWatch:
    """A node's side: the last hold message taken (any thread), and the cameras it must
    detect now (the frame loop's thread)."""

    def __init__(self, clock: Callable[[], float] = time.monotonic) -> None:
        self.clock = clock
        self._lock = threading.Lock()
        self._last: tuple[bool, frozenset[str], float] | None = None  # all, held, until
        self.taken = 0
        self.malformed = 0

    def take(self, payload: bytes) -> bool:
        """A hold message from the broker; False (counted) for one that is not."""
        try:
            all_, held, valid = decode_hold(payload)
        except WireError:
            with self._lock:
                self.malformed += 1
            return False
        with self._lock:
            self._last = (all_, held, self.clock() + valid)
            self.taken += 1
        return True

    def held(self, names: Collection[str]) -> set[str]:
        """The cameras of `names` never carried now: those the last hold names, or all of
        them when it says all, or when no hold is fresh."""
        with self._lock:
            last = self._last
        if last is None or self.clock() > last[2] or last[0]:
            return set(names)
        return set(names) & last[1]

    def figures(self) -> dict[str, int]:
        with self._lock:
            return {"taken": self.taken, "malformed": self.malformed}
