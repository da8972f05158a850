"""The site's tickets: each planned, active, completed or aborted, and what the frame loop asks
of them (pipeline.incidents.IncidentStep): every active ticket's events at a step, and the
zone events in a zone an active ticket isolated made info (kind "isolated", the ticket's id:
the equipment switched out and earthed for the job; its live neighbours stay alarms).

The API's thread adds, starts and ends tickets and binds roles; the loop's thread steps them.
A start or an end asked between two steps takes effect at the next step (its time is the
loop's clock): ticket_started, then the ticket's events; ticket_completed with its result.
At most MAX_KEPT ended tickets are kept (the oldest forgotten: their events are in the log).
"""

from __future__ import annotations

import threading
from collections.abc import Sequence
from enum import StrEnum

from stereopose.errors import StereoposeError
from stereopose.tickets.monitor import TICKET_KIND, TicketMonitor
from stereopose.tickets.ticket import TICKET_SLOTS, Ticket, check_zones
from stereopose.types import Event, People3D
from stereopose.zones import Zone
from stereopose.zones.safe import Safe, made_safe

__all__ = ["MAX_KEPT", "TicketDesk", "TicketError"]

MAX_KEPT = 200  # ended tickets kept
MAX_TICKETS = 1000  # tickets known at most (planned and active included)


class TicketState(StrEnum):
    """A ticket's state on the desk (as the API and the event log write it)."""

    PLANNED = "planned"
    ACTIVE = "active"
    COMPLETED = "completed"
    ABORTED = "aborted"


PLANNED, ACTIVE, COMPLETED, ABORTED = TicketState


class TicketError(StereoposeError):
    """A ticket cannot be added, started or ended (the API answers 404 or 409)."""

    def __init__(self, message: str, status: int = 409) -> None:
        super().__init__(message)
        self.status = status


class _Entry:
    def __init__(self, ticket: Ticket, monitor: TicketMonitor) -> None:
        self.ticket, self.monitor = ticket, monitor
        self.state: TicketState = PLANNED
        self.start_asked: str | None = None  # by whom (the loop starts it)
        self.end_asked: tuple[str, bool] | None = None  # by whom, aborted
        self.started_by: str | None = None
        self.ended_by: str | None = None
        self.started_t: float | None = None
        self.ended_t: float | None = None
        self.slot: int | None = None  # its IEC 104 slot while active (scada.points)


class TicketDesk:
    """See the module. zones: the site's zones (a ticket naming another is refused)."""

    def __init__(self, zones: Sequence[Zone], wall_start: float | None = None) -> None:
        """wall_start: the Unix time of t = 0 (serve's clock), if any: times shown as wall
        times too."""
        self.zones = tuple(zones)
        self._kinds = {z.name: z.kind for z in self.zones}
        self._lock = threading.Lock()
        self._entries: dict[str, _Entry] = {}
        self._isolating: dict[str, str] = {}  # zone -> the active ticket isolating it
        self.forgotten = 0
        self.wall_start = wall_start

    # -- the API's --------------------------------------------------------------------------

    def add(self, ticket: Ticket) -> dict:
        check_zones(ticket, self._kinds)
        with self._lock:
            if ticket.id in self._entries:
                raise TicketError(f"ticket {ticket.id!r} exists already")
            if len(self._entries) >= MAX_TICKETS:
                self._forget(force=True)
            self._entries[ticket.id] = _Entry(ticket, TicketMonitor(ticket, self.zones))
            return self._view(self._entries[ticket.id])

    def start(self, tid: str, by: str = "") -> dict:
        with self._lock:
            e = self._get(tid)
            if e.state != PLANNED or e.start_asked is not None:
                raise TicketError(f"ticket {tid!r} is {e.state}: only a planned one starts")
            e.start_asked = by
            return self._view(e)

    def end(self, tid: str, by: str = "", aborted: bool = False) -> dict:
        with self._lock:
            e = self._get(tid)
            if e.state in (COMPLETED, ABORTED) or e.end_asked is not None:
                raise TicketError(f"ticket {tid!r} has ended already")
            if e.state == PLANNED and e.start_asked is None:
                e.state, e.ended_by = ABORTED, by  # never started: nothing to evaluate
                return self._view(e)
            e.end_asked = (by, aborted)
            return self._view(e)

    def bind(self, tid: str, role: str, person: int) -> dict:
        """Bind `role` (operator, supervisor) of the ticket to a tracked person's id."""
        if role not in ("operator", "supervisor"):
            raise TicketError(f"no role {role!r}: operator or supervisor", 400)
        with self._lock:
            e = self._get(tid)
            if e.state in (COMPLETED, ABORTED):
                raise TicketError(f"ticket {tid!r} has ended")
            setattr(e.monitor, role, int(person))
            return self._view(e)

    def check_site(self, zones: Sequence[Zone]) -> None:
        """ConfigError when a ticket not yet ended names a zone `zones` lacks (or isolates one
        no longer energized): a new site must keep them."""
        kinds = {z.name: z.kind for z in zones}
        with self._lock:
            for e in self._entries.values():
                if e.state in (PLANNED, ACTIVE):
                    check_zones(e.ticket, kinds, f"ticket {e.ticket.id} ({e.state})")

    def set_zones(self, zones: Sequence[Zone]) -> None:
        """A new site's zones, for the tickets added or started from now on (an active ticket
        is followed with the zones it started with to its end)."""
        with self._lock:
            self.zones = tuple(zones)
            self._kinds = {z.name: z.kind for z in self.zones}

    def tickets(self) -> list[dict]:
        with self._lock:
            return [self._view(e, steps=False) for e in self._entries.values()]

    def ticket(self, tid: str) -> dict:
        with self._lock:
            return self._view(self._get(tid))

    def active(self) -> list[str]:
        with self._lock:
            return [t for t, e in self._entries.items() if e.state == ACTIVE]

    def active_or_starting(self) -> list[str]:
        """The tickets active, or asked to start."""
        with self._lock:
            return [
                t
                for t, e in self._entries.items()
                if e.state == ACTIVE or (e.state == PLANNED and e.start_asked is not None)
            ]

    # -- the loop's -------------------------------------------------------------------------

    def step(
        self, t: float, frame: int, people: People3D, postures: dict | None = None
    ) -> list[Event]:
        """Every active ticket's events at this step (the asked starts and ends first)."""
        out: list[Event] = []
        with self._lock:
            for e in list(self._entries.values()):
                if e.start_asked is not None and e.state == PLANNED:
                    if e.monitor.zones is not self.zones:  # the site changed since it was added
                        e.monitor = TicketMonitor(e.ticket, self.zones)
                    e.state, e.started_by, e.started_t = ACTIVE, e.start_asked, t
                    e.slot = self._free_slot()
                    e.start_asked = None
                    e.monitor.start(t)
                    out.append(_info(e.ticket, "ticket_started", t, frame))
                if e.state == ACTIVE:
                    out += e.monitor.step(t, frame, people, postures)
                if e.end_asked is not None and e.state == ACTIVE:
                    by, aborted = e.end_asked
                    out += e.monitor.end(t, frame, aborted)
                    e.state, e.ended_by, e.ended_t = (ABORTED if aborted else COMPLETED), by, t
                    e.end_asked, e.slot = None, None
            self._isolating = {
                z: tid
                for tid, e in self._entries.items()
                if e.state == ACTIVE
                for z in e.ticket.isolated
            }
            self._forget()
        return out

    def safe_now(self) -> dict[str, Safe]:
        """The zones an active ticket isolates (zones.safe): each with the ticket's id."""
        return {zone: Safe.isolated(ticket) for zone, ticket in self._isolating.items()}

    def relabel(self, events: Sequence[Event]) -> list[Event]:
        """The events, those of an energized zone an active ticket isolated as info (kind
        "isolated", the ticket's id)."""
        return made_safe(events, [self.safe_now()])

    def finish(self, t: float, frame: int) -> list[Event]:
        """Every active ticket ended now (the end of a run's input): its ticket_completed."""
        out: list[Event] = []
        with self._lock:
            for e in self._entries.values():
                if e.state == ACTIVE:
                    out += e.monitor.end(t, frame)
                    e.state, e.ended_t, e.slot = COMPLETED, t, None
            self._isolating = {}
        return out

    # -- parts ------------------------------------------------------------------------------

    def _free_slot(self) -> int | None:
        """The lowest slot no active ticket holds (as the outstation gives them), or None."""
        taken = {e.slot for e in self._entries.values() if e.slot is not None}
        return next((s for s in range(1, TICKET_SLOTS + 1) if s not in taken), None)

    def _get(self, tid: str) -> _Entry:
        e = self._entries.get(tid)
        if e is None:
            raise TicketError(f"no ticket {tid!r}", 404)
        return e

    def _forget(self, force: bool = False) -> None:
        ended = [t for t, e in self._entries.items() if e.state in (COMPLETED, ABORTED)]
        drop = max(0, len(ended) - MAX_KEPT) or (1 if force and ended else 0)
        for tid in ended[:drop]:
            del self._entries[tid]
            self.forgotten += 1

    def _view(self, e: _Entry, steps: bool = True) -> dict:
        m = e.monitor
        out = {
            "id": e.ticket.id,
            "title": e.ticket.title,
            "kind": e.ticket.kind,
            "state": e.state,
            "starting": e.start_asked is not None,
            "ending": e.end_asked is not None,
            "isolated": list(e.ticket.isolated),
            "operator": m.operator,
            "supervisor": m.supervisor,
            "started_t": e.started_t,
            "ended_t": e.ended_t,
            "started_by": e.started_by,
            "ended_by": e.ended_by,
            "steps_total": len(e.ticket.steps),
            "steps_done": sum(1 for s in m.steps if s.done_t is not None),
            "deviations": sum(m.deviation_counts.values()),
            "slot": e.slot,
        }
        wall = self._wall
        out["started_wall"], out["ended_wall"] = wall(e.started_t), wall(e.ended_t)
        if steps:
            out["steps"] = [
                {**s, "done_wall": wall(s["done_t"]), "onset_wall": wall(s["onset_t"])}
                for s in m.progress()
            ]
            out["ticket"] = e.ticket.to_dict()
            out["result"] = m.result() if e.state in (COMPLETED, ABORTED) else None
            out["deviation_list"] = [{**d, "wall_t": wall(d["t"])} for d in m.deviations]
        return out

    def _wall(self, t: float | None) -> float | None:
        """A ticket time (the loop's t) as Unix time, where the desk knows its clock."""
        if t is None or self.wall_start is None:
            return None
        return round(self.wall_start + t, 3)


def _info(ticket: Ticket, type_: str, t: float, frame: int) -> Event:
    return Event(
        t=t,
        frame=frame,
        person=-1,
        zone="",
        kind=TICKET_KIND,
        type=type_,
        onset_t=t,
        ticket=ticket.id,
    )
