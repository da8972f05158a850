"""The incident book: events in, one incident per hazard, and the changes to publish.

    book = IncidentBook(AlarmSettings.from_site(site), next_id=allocator)
    up = book.update(events, now)              # once per step, also with no events
    up.incidents[k]     # the incident id of events[k] (None: an info event)
    up.changes          # each change of an incident (MQTT `incidents`, the webhook, the log)
    up.notifications    # those that ask for a sound and a banner: new incidents only
    book.acknowledge(id, by, now) / book.shelve(id, by, reason, duration_s, now) / unshelve

Every alarm- or warning-level event (alarms.levels) belongs to the incident of its hazard. An
event of a hazard whose incident is active, or cleared less than its `rearm_s` ago, is an
occurrence of that incident: counted, its last time and priority updated, no notification.
Otherwise it raises a new incident, with a notification (the previous one, cleared, waits for
its acknowledgement apart). So an approach that becomes an entry, a hand going in and out of a
panel, an exit at the margin followed by a new approach: one incident. Shelving holds for the
hazard: while an operator's shelving runs, a new incident of the same hazard is born shelved,
without a notification (a camera flapping during maintenance stays quiet).

A zone's incident clears when the person has left the zone (its exit) and is not approaching
it. The fence raises no event when an approach ends, so the caller says which (zone, person)
pairs still hold (`holding`: inside or within the margin, fence.rules.FenceMonitor's
`inside.state | near.state`): an exit while the pair still holds does not clear, and an
incident whose pair no longer holds clears. Without it, an exit clears, and an incident that
only approached clears `approach_clear_s` after its last event. A behaviour incident clears
at its end event (person_up, `<type>_end`), a camera's at camera_up, a calibration's at
calibration_recovered, the service's at service_resumed.

First-out: when a second incident is raised within first_out_s of the first of a burst, the
first is marked first-out (a change), the others are not.

Bounded: a closed incident is forgotten once its re-arm time has passed; at most
max_incidents are kept (the oldest cleared ones, then the oldest, dropped and counted: they
are in the caller's log). Ids come from the caller's allocator (a persisted high-water mark),
so the book stays pure; `restore` takes the open incidents back after a restart, each id once.
Times: the events' clock (Event.t); `now` in the same clock.
"""

from __future__ import annotations

import heapq
import itertools
from collections.abc import Callable, Collection, Iterable, Sequence
from dataclasses import dataclass

from stereopose.alarms.incident import (
    CLEARED,
    CLOSED,
    MAX_SHELVE_S,
    Incident,
    IncidentError,
    IncidentRecord,
)
from stereopose.alarms.levels import HazardKey, clears, hazard_key, raises
from stereopose.alarms.priority import AlarmSettings
from stereopose.types import Event

__all__ = ["Change", "IncidentBook", "UnknownIncidentError", "Update"]

MAX_INCIDENTS = 10_000
FIRST_OUT_S = 10.0
APPROACH_CLEAR_S = 10.0
_INSIDE_TYPES = ("enter", "dwell")

# what a change is: a new incident, an occurrence, the condition ended, an operator's act,
# the first of a burst, one dropped from a full book
RAISED, OCCURRENCE, CLEAR, ACK = "raised", "occurrence", "cleared", "acknowledged"
SHELVED, UNSHELVED, FIRST_OUT, DROPPED = "shelved", "unshelved", "first_out", "dropped"


class UnknownIncidentError(IncidentError):
    """No open incident has this id (never raised, or closed and forgotten)."""


@dataclass(frozen=True)
class Change:
    """One change of one incident: `what` (raised, occurrence, cleared, acknowledged, shelved,
    unshelved, first_out, dropped), the state `before` it (None when raised), the incident
    after it, when (t), by whom (an operator's act; None otherwise) and whether it asks for a
    sound and a banner (notify: a new incident not shelved). wall_start: the Unix time of
    t = 0 when the caller knows it: to_dict then gives the wall times too (wall_t, and the
    incident's first_wall_t, last_wall_t, acked_wall_at, shelved_wall_until)."""

    what: str
    before: str | None
    incident: IncidentRecord
    t: float
    notify: bool = False
    by: str | None = None
    wall_start: float | None = None

    def to_dict(self) -> dict:
        wall = self.wall_start
        d = {
            "change": self.what,
            "before": self.before,
            "state": self.incident.state,
            "t": self.t,
            "notify": self.notify,
            "by": self.by,
            "incident": self.incident.to_dict(wall),
        }
        if wall is not None:
            d["wall_t"] = wall + self.t
        return d


@dataclass(frozen=True)
class Update:
    """incidents: per event given, its incident id (None: no incident); changes: in order."""

    incidents: tuple[int | None, ...]
    changes: tuple[Change, ...]

    @property
    def notifications(self) -> tuple[Change, ...]:
        return tuple(c for c in self.changes if c.notify)


class IncidentBook:
    """Incidents of a site's events (see the module's docstring).

    settings: per zone and rule priority and rearm_s; next_id: gives each new incident its
    id (increasing, never reused: the caller persists its high-water mark); first_out_s: the
    burst window; approach_clear_s: see `holding`; max_shelve_s: the longest shelving;
    max_incidents: the most kept in memory."""

    def __init__(
        self,
        settings: AlarmSettings | None = None,
        next_id: Callable[[], int] | None = None,
        *,
        first_out_s: float = FIRST_OUT_S,
        approach_clear_s: float = APPROACH_CLEAR_S,
        max_shelve_s: float = MAX_SHELVE_S,
        max_incidents: int = MAX_INCIDENTS,
    ) -> None:
        self.settings = settings or AlarmSettings()
        self.next_id = next_id or itertools.count(1).__next__
        self.first_out_s = float(first_out_s)
        self.approach_clear_s = float(approach_clear_s)
        self.max_shelve_s = float(max_shelve_s)
        self.max_incidents = int(max_incidents)
        self.dropped = 0  # incidents dropped because the book was full
        self._by_id: dict[int, Incident] = {}
        self._by_key: dict[HazardKey, int] = {}  # each hazard's latest incident
        self._inside: set[int] = set()  # zone incidents whose person is inside the zone
        self._zone_active: set[int] = set()  # zone incidents active
        # (time, id) heaps, checked lazily: when a closed incident may be forgotten, when a
        # shelving runs out, when an incident that only approached clears
        self._forget: list[tuple[float, int]] = []
        self._shelf: list[tuple[float, int]] = []
        self._approach: list[tuple[float, int]] = []
        self._burst: tuple[float, int] | None = None  # (time, id) of a burst's first
        self._shelved: dict[HazardKey, IncidentRecord] = {}  # each shelved hazard's shelving

    def retune(self, settings: AlarmSettings) -> None:
        """A new site's priorities and rearm times, for the events from now on; the open
        incidents keep theirs."""
        self.settings = settings

    # -- reading
    def __len__(self) -> int:
        return len(self._by_id)

    def __contains__(self, incident_id: object) -> bool:
        return incident_id in self._by_id

    def get(self, incident_id: int) -> IncidentRecord:
        inc = self._by_id.get(incident_id)
        if inc is None:
            raise UnknownIncidentError(f"no open incident {incident_id}")
        return inc.record()

    def incidents(self) -> list[IncidentRecord]:
        """Every incident kept (open, or closed within its re-arm time), oldest first."""
        return [self._by_id[i].record() for i in sorted(self._by_id)]

    # -- the one verb per step
    def update(
        self,
        events: Sequence[Event],
        now: float,
        *,
        event_ids: Sequence[int | None] | None = None,
        holding: Collection[tuple[str, int]] | None = None,
    ) -> Update:
        """The step's events (in order) at time now -> their incidents and the changes.
        event_ids: the caller's id of each event (stored as first/last event); holding: the
        (zone, person) pairs whose person is inside the zone or within its margin now."""
        if event_ids is not None and len(event_ids) != len(events):
            raise ValueError(f"{len(event_ids)} event ids for {len(events)} events")
        changes: list[Change] = []
        self._expire_shelving(now, changes)
        held = None if holding is None else {(str(z), int(p)) for z, p in holding}
        ids: list[int | None] = []
        for k, e in enumerate(events):
            for key in clears(e):
                # out of the zone but still at its margin: the hazard holds
                if held is None or key[0] != "zone" or (e.zone, e.person) not in held:
                    self._clear(key, e.t, changes)
            ids.append(self._event(e, None if event_ids is None else event_ids[k], changes))
        if held is not None:
            self._clear_not_holding(held, now, changes)
        self._clear_approaches(now, changes, act=held is None)
        self._forget_closed(now)
        self._bound(now, changes)
        return Update(tuple(ids), tuple(changes))

    def _current(self, key: HazardKey, t: float) -> Incident | None:
        """The hazard's incident an event at t belongs to: open, or cleared within re-arm."""
        i = self._by_key.get(key)
        inc = self._by_id.get(i) if i is not None else None
        if inc is None:
            return None
        if inc.active:
            return inc
        cleared_at = inc.record().cleared_at
        if cleared_at is not None and t - cleared_at <= inc.record().rearm_s:
            return inc
        return None

    def _event(self, e: Event, event_id: int | None, changes: list[Change]) -> int | None:
        if not raises(e):
            return None
        key = hazard_key(e)
        if key is None:
            return None
        priority = self.settings.priority(key, e.kind, e.type)
        inc = self._current(key, e.t)
        if inc is not None:
            before = inc.state
            inc.occur(e.t, e.type, priority, event_id)
            changes.append(Change(OCCURRENCE, before, inc.record(), e.t))
        else:
            rearm_s = self.settings.tuning(key).rearm_s
            inc = Incident.raised(self.next_id(), key, e.t, e.type, priority, rearm_s, event_id)
            self._by_id[inc.id] = inc
            self._by_key[key] = inc.id
            shelf = self._shelved.get(key)
            until = (shelf.shelved_until or 0.0) if shelf is not None else 0.0
            quiet = shelf is not None and until > e.t
            if shelf is not None and quiet:
                inc.shelve_as(shelf)
                heapq.heappush(self._shelf, (until, inc.id))
            changes.append(Change(RAISED, None, inc.record(), e.t, notify=not quiet))
            self._first_out(inc, e.t, changes)
        if key[0] == "zone":
            self._zone_active.add(inc.id)
            if e.type in _INSIDE_TYPES:
                self._inside.add(inc.id)
            elif inc.id not in self._inside:
                heapq.heappush(self._approach, (e.t + self.approach_clear_s, inc.id))
        return inc.id

    def _first_out(self, inc: Incident, t: float, changes: list[Change]) -> None:
        if self._burst is not None and t - self._burst[0] <= self.first_out_s:
            first = self._by_id.get(self._burst[1])
            if first is not None and first.mark_first_out():
                changes.append(Change(FIRST_OUT, first.state, first.record(), t))
            return
        self._burst = (t, inc.id)

    def _clear(self, key: HazardKey, t: float, changes: list[Change]) -> None:
        if key[0] == "ticket" and len(key) == 2:  # every hazard of the ticket
            for k in [k for k in self._by_key if k[:2] == key and len(k) > 2]:
                self._clear(k, t, changes)
            return
        i = self._by_key.get(key)
        inc = self._by_id.get(i) if i is not None else None
        if inc is None:
            return
        self._inside.discard(inc.id)
        self._zone_active.discard(inc.id)
        before = inc.state
        if inc.clear(t):
            changes.append(Change(CLEAR, before, inc.record(), t))
            heapq.heappush(self._forget, (t + inc.record().rearm_s, inc.id))

    def _clear_not_holding(
        self, held: set[tuple[str, int]], now: float, changes: list[Change]
    ) -> None:
        for i in list(self._zone_active):
            key = self._by_id[i].key
            if (str(key[1]), int(key[2])) not in held:
                self._clear(key, now, changes)

    def _clear_approaches(self, now: float, changes: list[Change], act: bool) -> None:
        """Clear the incidents that only approached, approach_clear_s after their last
        event (act: False when `holding` decides; the heap is emptied all the same)."""
        while self._approach and self._approach[0][0] <= now:
            _, i = heapq.heappop(self._approach)
            inc = self._by_id.get(i)
            if not act or inc is None or not inc.active or i in self._inside:
                continue
            # a later approach pushed a later deadline: this one is stale
            if inc.record().last_t + self.approach_clear_s > now:
                continue
            self._clear(inc.key, now, changes)

    def _forget_closed(self, now: float) -> None:
        while self._forget and self._forget[0][0] < now:
            _, i = heapq.heappop(self._forget)
            inc = self._by_id.get(i)
            if inc is not None and inc.state == CLOSED and self._rearmed(inc, now):
                self._drop(inc)

    @staticmethod
    def _rearmed(inc: Incident, now: float) -> bool:
        r = inc.record()
        return r.cleared_at is not None and now - r.cleared_at > r.rearm_s

    def _drop(self, inc: Incident) -> None:
        del self._by_id[inc.id]
        self._inside.discard(inc.id)
        self._zone_active.discard(inc.id)
        if self._by_key.get(inc.key) == inc.id:
            del self._by_key[inc.key]

    def _bound(self, now: float, changes: list[Change]) -> None:
        over = len(self._by_id) - self.max_incidents
        if over <= 0:
            return
        # the oldest returned-to-normal first (only an acknowledgement is missing), then the
        # oldest of the rest
        order = sorted(self._by_id.values(), key=lambda x: (x.state not in (CLEARED, CLOSED), x.id))
        for inc in order[:over]:
            self._drop(inc)
            self.dropped += 1
            changes.append(Change(DROPPED, inc.state, inc.record(), now))

    def _expire_shelving(self, now: float, changes: list[Change]) -> None:
        while self._shelf and self._shelf[0][0] <= now:
            until, i = heapq.heappop(self._shelf)
            inc = self._by_id.get(i)
            if inc is not None and inc.record().shelved_until == until and inc.expire(now):
                changes.append(Change(UNSHELVED, inc.state, inc.record(), now))
        for key in [k for k, r in self._shelved.items() if (r.shelved_until or 0.0) <= now]:
            del self._shelved[key]

    # -- an operator's acts
    def _find(self, incident_id: int) -> Incident:
        inc = self._by_id.get(incident_id)
        if inc is None:
            raise UnknownIncidentError(f"no open incident {incident_id}")
        return inc

    def acknowledge(self, incident_id: int, by: str, now: float) -> list[Change]:
        """Acknowledged by `by` at now; [] when it already was."""
        inc = self._find(incident_id)
        before = inc.state
        if not inc.acknowledge(by, now):
            return []
        if inc.state == CLOSED:
            r = inc.record()
            heapq.heappush(self._forget, ((r.cleared_at or now) + r.rearm_s, inc.id))
        return [Change(ACK, before, inc.record(), now, by=by)]

    def shelve(
        self, incident_id: int, by: str, reason: str, duration_s: float, now: float
    ) -> list[Change]:
        """Shelved by `by` with a reason for duration_s (at most max_shelve_s); an
        IncidentError says what is wrong."""
        inc = self._find(incident_id)
        inc.shelve(by, reason, duration_s, now, self.max_shelve_s)
        until = inc.record().shelved_until
        assert until is not None
        heapq.heappush(self._shelf, (until, inc.id))
        self._shelved[inc.key] = inc.record()
        return [Change(SHELVED, inc.state, inc.record(), now, by=by)]

    def unshelve(self, incident_id: int, by: str, now: float) -> list[Change]:
        inc = self._find(incident_id)
        self._shelved.pop(inc.key, None)
        if not inc.unshelve():
            return []
        return [Change(UNSHELVED, inc.state, inc.record(), now, by=by)]

    # -- a restart
    def restore(self, records: Iterable[IncidentRecord]) -> int:
        """Take back the incidents a previous process left open (from the caller's store);
        an id already here is skipped, never duplicated. Returns how many were taken."""
        taken = 0
        for rec in sorted(records, key=lambda r: r.id):
            if rec.id in self._by_id:
                continue
            inc = Incident(rec)
            self._by_id[rec.id] = inc
            self._by_key[rec.key] = rec.id
            taken += 1
            if rec.key[0] == "zone" and rec.active:
                self._zone_active.add(rec.id)
                if rec.last_type in _INSIDE_TYPES:
                    self._inside.add(rec.id)
                else:
                    heapq.heappush(self._approach, (rec.last_t + self.approach_clear_s, rec.id))
            if rec.cleared_at is not None:
                heapq.heappush(self._forget, (rec.cleared_at + rec.rearm_s, rec.id))
            if rec.shelved_until is not None:
                heapq.heappush(self._shelf, (rec.shelved_until, rec.id))
                self._shelved[rec.key] = rec
        return taken
