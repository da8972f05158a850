"""Carried steps: between detections, a camera whose people move slowly skips the detector
every other step, its people carried from its last detection.

    carry = Carrier(CarrySettings())
    skip = carry.plan(["cam01", "cam02"], step, t)   # the cameras carried at this step
    ...detect the others...
    carry.seen("cam01", people, t)                   # each camera detected
    people = carry.carried("cam02", step)           # each camera carried

A camera is carried at a step only when all of these hold:
- its last step was detected (never two carried steps in a row, so an alarm waits at most one
  extra step for a camera, and the other cameras see it at once);
- the step is its turn: the cameras take turns by step parity, so about half of them detect
  at every step;
- its last two detections hold the same number of people, each matched one-to-one to the
  nearest of the other, and no joint of theirs that the detector is sure of (SURE) moved
  more than `motion` of its person's height between the two: a hand reaching out, a walk
  past a slow camera (1.2 m/s is about 7 % of a worker's height per step at 10 steps/s) are
  detected at every step; the slow work at a bay is carried;
- no person it sees is near a hazard: `plan`'s `hold` names the cameras that see someone
  within an energized, live zone's approach distance plus a hand's motion until the step
  (zones.hazard, pipeline.sources.Cameras); near a hazard every camera detects at every step,
  so an alarm there is never a step late.

A carried camera's people are its last detection's, as they were (a slow worker moves less in
one step than the detector's own jitter between two: on the real demo, moving them on at
their measured pace reprojected worse, 11.0 px against 10.8); the 3D stage triangulates them
with the detected cameras' people as usual.
"""

from __future__ import annotations

from collections.abc import Callable, Collection
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from stereopose.types import People2D

if TYPE_CHECKING:
    from stereopose.config import DetectorConfig

# a joint this sure in both detections counts in a person's motion (a joint the detector
# doubts jumps about without anyone moving)
SURE = 0.5


@dataclass(frozen=True)
class CarrySettings:
    """motion: the most a camera's person may move between its last two detections, as a
    share of his height (box), for the camera to be carried at its next step."""

    motion: float = 0.05

    def __post_init__(self) -> None:
        if not 0 < self.motion <= 1:
            raise ValueError(f"carry motion must be in (0, 1], got {self.motion!r}")


@dataclass
class _Seen:
    """A camera's last two detections (people, the step and time of each) and its figures."""

    last: tuple[People2D, int, float] | None = None
    before: tuple[People2D, int, float] | None = None
    turn: int = 0  # carried at steps of this parity (the cameras take turns)
    slow: bool = False  # its people moved slowly between them: it may be carried
    detected: int = 0
    carried: int = 0
    held: int = 0  # steps it would have been carried but for someone near a hazard


def _centres(people: People2D) -> np.ndarray:
    """Each person's centre (P, 2): his box's, or his joints' where he has no box."""
    if people.boxes is not None:
        b = np.asarray(people.boxes, float)
        return np.column_stack([(b[:, 0] + b[:, 2]) / 2, (b[:, 1] + b[:, 3]) / 2])
    return np.array([np.nanmean(p[:, :2], axis=0) for p in people.keypoints]).reshape(-1, 2)


def _heights(people: People2D) -> np.ndarray:
    """Each person's height in pixels (P,): his box's, or his joints' extent."""
    if people.boxes is not None:
        b = np.asarray(people.boxes, float)
        return b[:, 3] - b[:, 1]
    y = people.keypoints[..., 1]
    return np.array([np.nanmax(r) - np.nanmin(r) if np.isfinite(r).any() else 0.0 for r in y])


def _match(last: People2D, before: People2D) -> list[int] | None:
    """For each of `last`'s people, the index of the same person in `before` (nearest centres,
    one-to-one, greedy by distance); None when their numbers differ."""
    if len(last) != len(before):
        return None
    if not len(last):
        return []
    a, b = _centres(last), _centres(before)
    d = np.linalg.norm(a[:, None] - b[None], axis=-1)
    d = np.where(np.isfinite(d), d, np.inf)
    out = [-1] * len(last)
    used: set[int] = set()
    for flat in np.argsort(d, axis=None, kind="stable"):
        i, j = divmod(int(flat), len(before))
        if out[i] < 0 and j not in used and np.isfinite(d[i, j]):
            out[i] = j
            used.add(j)
    return None if -1 in out else out


class Carrier:
    """Which cameras are carried at each step, and their carried people (see the module).
    One per run or service, for all its cameras; the detection thread's alone."""

    def __init__(self, settings: CarrySettings | None = None) -> None:
        self.settings = settings or CarrySettings()
        self._cameras: dict[str, _Seen] = {}

    def plan(
        self,
        names: list[str],
        step: int,
        t: float,
        hold: Collection[str] | Callable[[list[str]], Collection[str]] = (),
    ) -> set[str]:
        """The cameras of `names` (those with a picture at this step) carried at `step`;
        hold: cameras that see someone near a hazard, never carried (counted as held), or
        what names them among the cameras that would be carried (asked only when there is
        one: finding who is near a hazard costs a millisecond a step)."""
        ready = [name for name in names if self._ready(name, step, t)]
        if not ready:
            return set()
        held = hold(ready) if callable(hold) else hold
        out = set()
        for name in ready:
            if name in held:
                self._cameras[name].held += 1
            else:
                out.add(name)
        return out

    def _ready(self, name: str, step: int, t: float) -> bool:
        """Whether camera `name` may be carried at `step` but for a hazard."""
        seen = self._cameras.get(name)
        if seen is None or not seen.slow or seen.last is None:
            return False
        # its last step was carried (or missed), or not its turn
        return seen.last[1] == step - 1 and not (step + seen.turn) % 2 and t > seen.last[2]

    def seen(self, name: str, people: People2D, step: int, t: float) -> None:
        """Camera `name`'s people detected at `step`, time t."""
        seen = self._cameras.setdefault(name, _Seen(turn=len(self._cameras) % 2))
        seen.detected += 1
        seen.before, seen.last = seen.last, (people, step, t)
        seen.slow = self._slow(seen)

    def carried(self, name: str, step: int) -> People2D:
        """Camera `name`'s people at `step` (a camera `plan` carried): its last detection's,
        as they were."""
        seen = self._cameras[name]
        assert seen.last is not None and seen.slow
        last = seen.last[0]
        seen.carried += 1
        return People2D(name, step, last.keypoints, last.boxes, last.scores)

    def _slow(self, seen: _Seen) -> bool:
        """Whether the camera's people, matched between its last two detections, all moved
        less than `motion` of their height between them."""
        if seen.last is None or seen.before is None:
            return False
        last, before = seen.last[0], seen.before[0]
        pairs = _match(last, before)
        if pairs is None:
            return False
        if not pairs:
            return True
        moved = last.keypoints[:, :, :2] - before.keypoints[pairs, :, :2]
        dist = np.linalg.norm(moved, axis=-1)  # (P, 17)
        sure = (last.keypoints[:, :, 2] >= SURE) & (before.keypoints[pairs, :, 2] >= SURE)
        dist = np.where(np.isfinite(dist) & sure, dist, 0.0)
        return bool((dist.max(axis=1) <= self.settings.motion * _heights(last)).all())

    def report(self) -> dict[str, dict[str, int]]:
        """Per camera, the steps detected and carried, and of those detected, the steps it
        would have been carried but for someone near a hazard (near_hazard)."""
        return {
            n: {"detected": s.detected, "carried": s.carried, "near_hazard": s.held}
            for n, s in self._cameras.items()
        }


def carrier(settings: DetectorConfig) -> Carrier | None:
    """The Carrier of a run's `[detector]` settings (config.DetectorConfig: carry,
    carry_motion); None with carry = false."""
    if not settings.carry:
        return None
    return Carrier(CarrySettings(motion=settings.carry_motion))
