"""One incident: a hazard's alarm as an ISA-18.2 state machine, pure.

An incident is active or cleared (returned to normal), and acknowledged or not, independently;
the four combinations are its `state`:

    active        active, unacknowledged     (the banner holds it; a sound when raised)
    acknowledged  active, acknowledged
    cleared       returned to normal, unacknowledged (shown cleared, still to acknowledge)
    closed        returned to normal and acknowledged (done)

    occur        an occurrence: active again (cleared -> active, closed -> acknowledged: the
                 operator already knows this hazard; re-arm is the book's business)
    clear        the condition ended: active -> cleared, acknowledged -> closed
    acknowledge  by an operator: active -> acknowledged, cleared -> closed
    shelve       by an operator, with a reason, until a time at most max_shelve_s ahead;
                 orthogonal to the state (a shelved incident is still counted and logged);
                 unshelved by an operator or when the time comes (`expire`)

Each transition returns whether it changed anything; an operator's act that makes no sense
(shelving a closed incident, without a reason, for too long) is an IncidentError.
Incident.record() is the frozen snapshot that leaves the package (API, MQTT, the log) and
IncidentRecord.from_dict reads one back (a restart).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields, replace
from typing import Any

from stereopose.alarms.levels import HazardKey
from stereopose.errors import StereoposeError
from stereopose.types import JsonDoc

__all__ = [
    "ACKNOWLEDGED",
    "ACTIVE",
    "CLEARED",
    "CLOSED",
    "MAX_SHELVE_S",
    "STATES",
    "WALL_TIMES",
    "Incident",
    "IncidentError",
    "IncidentRecord",
    "with_wall_times",
]

ACTIVE, ACKNOWLEDGED, CLEARED, CLOSED = "active", "acknowledged", "cleared", "closed"
STATES = (ACTIVE, ACKNOWLEDGED, CLEARED, CLOSED)
MAX_SHELVE_S = 8 * 3600.0  # an operator may shelve for at most a shift
MAX_REASON = 500  # characters of a shelving reason kept


class IncidentError(StereoposeError, ValueError):
    """An operator's act on an incident that cannot be done (the message says why)."""


@dataclass(frozen=True)
class IncidentRecord:
    """An incident as it is at one moment. Times in the clock of the events' `t` (seconds);
    key: the hazard (alarms.levels); type: the event type that raised it, last_type the
    latest occurrence's, worst_type that of its most urgent occurrence (the first of them;
    "" in a record of an earlier version: read `type`); first_event / last_event: the
    caller's ids of those events (None when the caller gave none); first_out: the first of a
    burst of incidents."""

    id: int
    key: HazardKey
    state: str
    priority: int
    type: str
    last_type: str
    occurrences: int
    first_t: float
    last_t: float
    active_since: float | None
    cleared_at: float | None = None
    closed_at: float | None = None
    acked_by: str | None = None
    acked_at: float | None = None
    shelved_until: float | None = None
    shelved_by: str | None = None
    shelved_reason: str | None = None
    rearm_s: float = 30.0
    first_event: int | None = None
    last_event: int | None = None
    first_out: bool = False
    worst_type: str = ""

    @property
    def shelved(self) -> bool:
        return self.shelved_until is not None

    @property
    def active(self) -> bool:
        return self.state in (ACTIVE, ACKNOWLEDGED)

    @property
    def zone(self) -> str | None:
        return str(self.key[1]) if self.key[0] in ("zone", "left_work_area") else None

    @property
    def rule(self) -> str | None:
        return str(self.key[1]) if self.key[0] == "rule" else None

    @property
    def person(self) -> int | None:
        return int(self.key[2]) if self.key[0] in ("zone", "left_work_area", "rule") else None

    @property
    def camera(self) -> str | None:
        return str(self.key[1]) if self.key[0] in ("camera", "calibration") else None

    def to_dict(self, wall_start: float | None = None) -> dict[str, object]:
        """JSON-ready: the fields, the key as a list, and zone / rule / person / camera /
        shelved spelled out for readers that do not parse keys; with wall_start (the Unix
        time of t = 0) the wall times too (WALL_TIMES)."""
        d = asdict(self)
        d["key"] = list(self.key)
        d.update(
            zone=self.zone,
            rule=self.rule,
            person=self.person,
            camera=self.camera,
            shelved=self.shelved,
        )
        if wall_start is not None:
            with_wall_times(d, wall_start)
        return d

    @classmethod
    def from_dict(cls, d: JsonDoc) -> IncidentRecord:
        """Back from to_dict (extra keys ignored); a bad record is an IncidentError."""
        names = {f.name for f in fields(cls)}
        try:
            kw = {k: v for k, v in d.items() if k in names}
            kw["key"] = tuple(kw["key"])
            rec = cls(**kw)
        except (KeyError, TypeError) as e:
            raise IncidentError(f"not an incident record: {e}") from None
        if rec.state not in STATES:
            raise IncidentError(f"incident {rec.id}: unknown state {rec.state!r}")
        return rec


# each wall time of a record's dict (Unix seconds) and the time on the events' clock it is of
WALL_TIMES = (
    ("first_wall_t", "first_t"),
    ("last_wall_t", "last_t"),
    ("acked_wall_at", "acked_at"),
    ("shelved_wall_until", "shelved_until"),
)


def with_wall_times(d: dict[str, object], wall_start: float | None) -> dict[str, object]:
    """d (a record's dict) with its WALL_TIMES: wall_start + t (None without either)."""
    for name, key in WALL_TIMES:
        t = d.get(key)
        d[name] = wall_start + t if wall_start is not None and isinstance(t, (int, float)) else None
    return d


class Incident:
    """The mutable incident the book keeps; `record()` gives its snapshot."""

    def __init__(self, rec: IncidentRecord) -> None:
        self._rec = rec

    @classmethod
    def raised(
        cls,
        id_: int,
        key: HazardKey,
        t: float,
        type_: str,
        priority: int,
        rearm_s: float,
        event_id: int | None = None,
    ) -> Incident:
        """A new incident, active and unacknowledged, with its first occurrence at t."""
        return cls(
            IncidentRecord(
                id=id_,
                key=key,
                state=ACTIVE,
                priority=priority,
                type=type_,
                last_type=type_,
                worst_type=type_,
                occurrences=1,
                first_t=t,
                last_t=t,
                active_since=t,
                rearm_s=rearm_s,
                first_event=event_id,
                last_event=event_id,
            )
        )

    def record(self) -> IncidentRecord:
        return self._rec

    @property
    def id(self) -> int:
        return self._rec.id

    @property
    def key(self) -> HazardKey:
        return self._rec.key

    @property
    def state(self) -> str:
        return self._rec.state

    @property
    def active(self) -> bool:
        return self._rec.active

    @property
    def acknowledged(self) -> bool:
        return self._rec.state in (ACKNOWLEDGED, CLOSED)

    def _set(self, **changes: Any) -> None:
        self._rec = replace(self._rec, **changes)

    def occur(self, t: float, type_: str, priority: int, event_id: int | None = None) -> bool:
        """One more occurrence at t (always a change: the count); active again if cleared,
        and the priority rises to the occurrence's when that is more urgent."""
        r = self._rec
        state = r.state
        if state == CLEARED:
            state = ACTIVE
        elif state == CLOSED:
            state = ACKNOWLEDGED
        last_event = event_id if event_id is not None else r.last_event
        worst = type_ if priority < r.priority else (r.worst_type or r.type)
        self._set(
            state=state,
            occurrences=r.occurrences + 1,
            last_t=max(r.last_t, t),
            last_type=type_,
            worst_type=worst,
            priority=min(r.priority, priority),
            active_since=r.active_since if r.active else t,
            cleared_at=None,
            closed_at=None,
            last_event=last_event,
        )
        return True

    def clear(self, t: float) -> bool:
        """The condition ended at t: returned to normal (closed when acknowledged)."""
        r = self._rec
        if not r.active:
            return False
        closed = r.state == ACKNOWLEDGED
        self._set(
            state=CLOSED if closed else CLEARED,
            cleared_at=t,
            active_since=None,
            closed_at=t if closed else None,
        )
        return True

    def acknowledge(self, by: str, t: float) -> bool:
        """An operator `by` acknowledged at t: active -> acknowledged, cleared -> closed; an
        incident already acknowledged stays as it is (False)."""
        r = self._rec
        if self.acknowledged:
            return False
        state = ACKNOWLEDGED if r.state == ACTIVE else CLOSED
        self._set(
            state=state, acked_by=str(by), acked_at=t, closed_at=t if state == CLOSED else None
        )
        return True

    def shelve(
        self, by: str, reason: str, duration_s: float, t: float, max_shelve_s: float = MAX_SHELVE_S
    ) -> bool:
        """Shelved by `by` at t for duration_s (0 < duration_s <= max_shelve_s) with a reason
        (non-empty); a shelved incident may be shelved again (the new time replaces the old)."""
        if self._rec.state == CLOSED:
            raise IncidentError(f"incident {self.id} is closed: nothing to shelve")
        text = (reason or "").strip()
        if not text:
            raise IncidentError("shelving needs a reason")
        ok = isinstance(duration_s, (int, float)) and not isinstance(duration_s, bool)
        if not ok or not math.isfinite(duration_s) or not 0 < duration_s <= max_shelve_s:
            raise IncidentError(
                f"shelving lasts more than 0 s and at most {max_shelve_s:g} s, got {duration_s!r}"
            )
        self._set(
            shelved_until=t + float(duration_s),
            shelved_by=str(by),
            shelved_reason=text[:MAX_REASON],
        )
        return True

    def shelve_as(self, other: IncidentRecord) -> None:
        """Shelved as `other` is (a new incident of a hazard the operator has shelved)."""
        self._set(
            shelved_until=other.shelved_until,
            shelved_by=other.shelved_by,
            shelved_reason=other.shelved_reason,
        )

    def unshelve(self) -> bool:
        """Back in service (an operator's act, or the shelving's time ran out)."""
        if self._rec.shelved_until is None:
            return False
        self._set(shelved_until=None, shelved_by=None, shelved_reason=None)
        return True

    def expire(self, now: float) -> bool:
        """Unshelve when the shelving's time has come (<= now)."""
        until = self._rec.shelved_until
        return until is not None and until <= now and self.unshelve()

    def mark_first_out(self) -> bool:
        if self._rec.first_out:
            return False
        self._set(first_out=True)
        return True
