"""The tickets as the SCADA sees them (IEC 104's ticket points, OPC UA's Tickets folder): up to
TICKET_SLOTS active tickets, each in the lowest slot free when it started, freed when it ends
(its ticket_completed), with its steps done; a slot's ticket deviates while one of its
incidents is not closed (active, or not yet acknowledged: a step's incident clears as soon as
the step is done, often in the same step)."""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field

from stereopose.alarms import IncidentRecord
from stereopose.tickets.ticket import TICKET_SLOTS
from stereopose.types import Event

__all__ = ["SlotRow", "TicketSlots", "deviating"]


@dataclass(frozen=True)
class SlotRow:
    """One slot now: its number (1 ..), the ticket in it (None: free), whether one is active
    and deviates, its steps done."""

    slot: int
    ticket: str | None
    active: bool
    deviation: bool
    steps_done: int


@dataclass
class TicketSlots:
    """See the module; `event(e)` folds a ticket's event in."""

    slots: list[str | None] = field(default_factory=lambda: [None] * TICKET_SLOTS)
    steps_done: dict[str, int] = field(default_factory=dict)

    def event(self, e: Event) -> bool:
        """A ticket's event folded in (started: the lowest free slot; a step done; ended: its
        slot freed); whether it changed a slot."""
        tid = e.ticket
        if tid is None:  # not a ticket's event
            return False
        if e.type == "ticket_started" and tid not in self.slots and None in self.slots:
            self.slots[self.slots.index(None)] = tid
            self.steps_done[tid] = 0
        elif e.type == "step_done" and tid in self.steps_done:
            self.steps_done[tid] += 1
        elif e.type == "ticket_completed" and tid in self.slots:
            self.slots[self.slots.index(tid)] = None
            self.steps_done.pop(tid, None)
        else:
            return False
        return True

    def rows(self, deviating_tickets: set[str]) -> list[SlotRow]:
        return [
            SlotRow(
                k + 1,
                tid,
                tid is not None,
                tid is not None and tid in deviating_tickets,
                self.steps_done.get(tid, 0) if tid is not None else 0,
            )
            for k, tid in enumerate(self.slots)
        ]


def deviating(records: Iterable[IncidentRecord]) -> set[str]:
    """The tickets with an incident not closed, among open incident records."""
    return {
        str(r.key[1]) for r in records if r.key and r.key[0] == "ticket" and r.state != "closed"
    }
