"""Alarm-rate figures of an operator's load (EEMUA 191 / ISA-18.2), over sliding windows.

    rates = AlarmRates()
    rates.observe(update.changes)          # each step's changes from the IncidentBook
    figures = rates.figures(now, book.incidents())

notifications_10min / notifications_1h: notifications (a sound and a banner: new incidents)
in the last 10 minutes / hour, against the flood line (more than FLOOD_PER_10MIN in 10 minutes
is a flood). chattering: hazards that raised CHATTER_COUNT or more notifications within
CHATTER_S (a defect: with re-arm they should be 0); chattering_occurrences: incidents with
CHATTER_COUNT or more occurrences within CHATTER_S (the hazard chatters, the book holds it in
one incident). standing: incidents active for longer than standing_s.

Memory is bounded: only the last hour of notifications (at most max_events, the oldest
dropped and counted) and the last CHATTER_S of occurrences are kept.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterable
from dataclasses import asdict, dataclass

from stereopose.alarms.book import OCCURRENCE, RAISED, Change
from stereopose.alarms.incident import IncidentRecord
from stereopose.alarms.levels import HazardKey

__all__ = ["CHATTER_COUNT", "CHATTER_S", "FLOOD_PER_10MIN", "AlarmRates", "RateFigures"]

TEN_MIN_S, HOUR_S = 600.0, 3600.0
FLOOD_PER_10MIN = 10
CHATTER_COUNT, CHATTER_S = 3, 60.0
STANDING_S = 24 * 3600.0
MAX_EVENTS = 100_000


@dataclass(frozen=True)
class RateFigures:
    notifications_10min: int
    notifications_1h: int
    flood_line: int
    flood: bool
    chattering: int
    chattering_occurrences: int
    standing: int
    dropped: int  # notifications dropped from the full window (the 1-hour figure is low)

    def to_dict(self) -> dict:
        return asdict(self)


class AlarmRates:
    """The sliding windows of notifications and occurrences (see the module's docstring)."""

    def __init__(self, standing_s: float = STANDING_S, max_events: int = MAX_EVENTS) -> None:
        self.standing_s = float(standing_s)
        self.max_events = int(max_events)
        self.dropped = 0  # notifications dropped from a full window
        self.dropped_occurrences = 0
        self._notified: deque[tuple[float, HazardKey]] = deque()
        self._occurred: deque[tuple[float, int]] = deque()
        self._latest = float("-inf")

    def observe(self, changes: Iterable[Change]) -> None:
        """Count the notifications and occurrences among `changes` (in time order)."""
        for c in changes:
            self._latest = max(self._latest, c.t)
            self._prune(self._latest)  # what has left the windows makes room first
            if c.notify:
                self.dropped += self._push(self._notified, (c.t, c.incident.key))
            if c.what in (RAISED, OCCURRENCE):
                self.dropped_occurrences += self._push(self._occurred, (c.t, c.incident.id))

    def _push(self, window: deque, item: tuple) -> int:
        """Append; 1 when the oldest had to go to make room."""
        full = len(window) >= self.max_events
        if full:
            window.popleft()
        window.append(item)
        return int(full)

    def _prune(self, now: float) -> None:
        # each window is (now - length, now]
        while self._notified and self._notified[0][0] <= now - HOUR_S:
            self._notified.popleft()
        while self._occurred and self._occurred[0][0] <= now - CHATTER_S:
            self._occurred.popleft()

    def figures(self, now: float, incidents: Iterable[IncidentRecord] = ()) -> RateFigures:
        """The figures at now; incidents: the book's (for the standing ones)."""
        self._prune(now)
        last10 = sum(1 for t, _ in self._notified if t > now - TEN_MIN_S)
        chatter = _repeated(((t, k) for t, k in self._notified if t > now - CHATTER_S))
        repeats = _repeated(((t, i) for t, i in self._occurred if t > now - CHATTER_S))
        standing = sum(
            1
            for r in incidents
            if r.active and r.active_since is not None and now - r.active_since > self.standing_s
        )
        return RateFigures(
            notifications_10min=last10,
            notifications_1h=len(self._notified),
            flood_line=FLOOD_PER_10MIN,
            flood=last10 > FLOOD_PER_10MIN,
            chattering=chatter,
            chattering_occurrences=repeats,
            standing=standing,
            dropped=self.dropped,
        )


def _repeated(items: Iterable[tuple[float, object]]) -> int:
    """How many names occur CHATTER_COUNT or more times among (time, name) items."""
    counts: dict[object, int] = {}
    for _, name in items:
        counts[name] = counts.get(name, 0) + 1
    return sum(1 for n in counts.values() if n >= CHATTER_COUNT)
