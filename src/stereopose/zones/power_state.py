"""Each energized zone's state from its breakers and earthing switches (zones.power): live,
dead or unknown, fail safe.

The sources (site.zone_sources) put each point's latest reading on a `PowerBoard`: its value,
whether its quality is good, and when it came. Once per step `ZoneStates.step` judges every
zone with a state source:

- **unknown** (counted as live) while any of its points has no value yet, its link is lost,
  its quality is invalid, or it is stale (no update within its stale bound: 1.5 interrogation
  periods by default); the zone's `zone_unknown` event names the point's source and why, an
  alarm-level diagnostic (its incident, keyed ("power", zone), clears when the zone is known
  again). At start a zone is unknown, and says so after `start_s` if it still is (the links
  take a moment to come up and answer their first interrogation);
- otherwise **dead** or **live** by the zone's rule: `zone_dead` / `zone_live` events, info.

While a zone is dead its enter, approach, dwell and exit events are relabelled kind "dead"
(info, with the state's source): touching equipment switched out and earthed is the job. When
a dead zone turns live or unknown while someone is inside (or approaching), an `enter` (or
`approach`) of the now live zone is raised at once for each of them: an alarm, as if they had
just come in.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from stereopose.types import Event
from stereopose.zones.safe import Safe, made_safe
from stereopose.zones.zone import Zone

__all__ = [
    "DEAD",
    "LIVE",
    "UNKNOWN",
    "PowerBoard",
    "Reading",
    "ZoneStates",
    "entries",
    "state_event",
]

LIVE, DEAD, UNKNOWN = "live", "dead", "unknown"
START_S = 10.0


@dataclass(frozen=True)
class Reading:
    """A point's latest reading: value (None: none), good quality, when (monotonic), and
    why it is not usable (empty when it is)."""

    value: Any = None
    valid: bool = False
    at: float | None = None
    reason: str = "no value yet"


class PowerBoard:
    """The points' latest readings by source label, written by the sources' threads."""

    def __init__(self, clock: Callable[[], float] = time.monotonic) -> None:
        self.clock = clock
        self._lock = threading.Lock()
        self._readings: dict[str, Reading] = {}
        self.updates = 0

    def set(self, key: str, value: object, valid: bool = True, reason: str = "") -> None:
        """A reading of point `key` now (valid False: its quality is invalid, `reason`)."""
        if not valid and not reason:
            reason = "invalid quality"
        with self._lock:
            self._readings[key] = Reading(value, valid, self.clock(), reason)
            self.updates += 1

    def lost(self, keys: Sequence[str], reason: str) -> None:
        """The points' link is lost: no usable value until they are read again."""
        now = self.clock()
        with self._lock:
            for key in keys:
                self._readings[key] = Reading(None, False, now, reason)

    def read(self, key: str) -> Reading:
        with self._lock:
            return self._readings.get(key, Reading())


@dataclass
class _State:
    state: str = UNKNOWN
    source: str = ""
    reason: str = "not read yet"
    since_wall: float | None = None
    said: bool = False  # its state's event sent (unknown is said only after start_s)


class ZoneStates:
    """See the module. zones: the site's zones (those with a `power` spec are judged);
    board: their points' readings; clock: the board's clock; wall: the Unix time."""

    def __init__(
        self,
        zones: Sequence[Zone],
        board: PowerBoard,
        *,
        start_s: float = START_S,
        wall: Callable[[], float] = time.time,
    ) -> None:
        self.zones = tuple(z for z in zones if z.power is not None)
        self.board, self.start_s, self.wall = board, float(start_s), wall
        self.started = board.clock()
        self._lock = threading.Lock()
        self._states = {z.name: _State(since_wall=wall()) for z in self.zones}
        self._dead: dict[str, str] = {}  # dead zone -> its source (the relabelling's)

    def judge(self, zone: Zone) -> tuple[str, str, str]:
        """(state, source, reason) of a zone now."""
        spec = zone.power
        assert spec is not None  # the zones of a PowerStates have a power rule
        values: dict[str, object] = {}
        now = self.board.clock()
        for p in spec.points:
            r = self.board.read(p.label)
            if r.value is None or not r.valid:
                return UNKNOWN, p.label, r.reason or "no value"
            bound = spec.stale_after(p)
            if bound is not None and r.at is not None and now - r.at > bound:
                return UNKNOWN, p.label, f"stale: no update for {now - r.at:.0f} s"
            values[p.name] = r.value
        labels = ", ".join(p.label for p in spec.points)
        try:
            dead = spec.is_dead(values)
        except (ValueError, TypeError, KeyError) as e:
            return UNKNOWN, labels, f"its rule cannot be judged: {e}"
        return (DEAD if dead else LIVE), labels, ""

    def step(self, t: float, frame: int, fences: Occupancy | None = None) -> list[Event]:
        """The zones' state changes at this step, and the entries of zones turned live with
        people inside (fences: the FenceMonitor, whose occupants they are)."""
        out: list[Event] = []
        waited = self.board.clock() - self.started >= self.start_s
        with self._lock:
            for z in self.zones:
                s = self._states[z.name]
                state, source, reason = self.judge(z)
                changed = (state, source, reason) != (s.state, s.source, s.reason)
                if changed and state != s.state:
                    s.since_wall = self.wall()
                was = s.state
                s.state, s.source, s.reason = state, source, reason
                if state == UNKNOWN and not waited and not s.said:
                    continue  # the links have a moment to come up
                if not changed and s.said:
                    continue
                if changed and state == UNKNOWN and was == UNKNOWN and s.said:
                    continue  # still unknown, for another reason: said once
                s.said = True
                text = f"{source}: {reason}" if reason else source
                out.append(state_event(t, frame, z, f"zone_{state}", text))
                if was == DEAD and state != DEAD and fences is not None:
                    out += entries(t, frame, z, fences, text)
            self._dead = {n: s.source for n, s in self._states.items() if s.state == DEAD}
        return out

    def safe_now(self) -> dict[str, Safe]:
        """The dead zones (zones.safe): each with its state's source."""
        return {zone: Safe.dead(source) for zone, source in self._dead.items()}

    def relabel(self, events: Sequence[Event]) -> list[Event]:
        """The events, a dead zone's entries as kind "dead" (info) with the state's source."""
        return made_safe(events, [self.safe_now()])

    def snapshot(self) -> dict[str, dict]:
        """zone -> {"state", "source", "reason", "since"} (since: Unix time)."""
        with self._lock:
            return {
                n: {
                    "state": s.state,
                    "source": s.source,
                    "reason": s.reason or None,
                    "since": s.since_wall,
                }
                for n, s in self._states.items()
            }


def state_event(t: float, frame: int, zone: Zone, type_: str, source: str) -> Event:
    return Event(
        t=t,
        frame=frame,
        person=-1,
        zone=zone.name,
        kind=zone.kind,
        type=type_,
        onset_t=t,
        source=source,
    )


class Occupancy(Protocol):
    """Who is in and near each zone now (fence.FenceMonitor)."""

    def occupants(
        self, zone: str
    ) -> tuple[list[tuple[int, np.ndarray]], list[tuple[int, np.ndarray]]]:
        """(inside, near): (person id, floor position) pairs."""
        ...


def entries(t: float, frame: int, zone: Zone, fences: Occupancy, source: str) -> list[Event]:
    """An enter for each person inside the zone now turned live, an approach for each one
    within its margin: alarms at once."""
    inside, near = fences.occupants(zone.name)
    out = []
    for type_, people in (("enter", inside), ("approach", near)):
        for pid, xy in people:
            out.append(
                Event(
                    t=t,
                    frame=frame,
                    person=int(pid),
                    zone=zone.name,
                    kind=zone.kind,
                    type=type_,
                    onset_t=t,
                    source=source,
                    position=None
                    if xy is None or not np.isfinite(xy).all()
                    else (float(xy[0]), float(xy[1])),
                )
            )
    return out
