"""Whether an energized zone is safe now, judged in one place: dead by its breakers and
earthing switches (zones.power_state), or isolated by an active work ticket (tickets). A safe
zone's events are information, never alarms: each rule that knows a zone safe says so with a
`Safe`, and `made_safe` rewrites the step's events of that zone, in the rules' order (a zone
found dead is not isolated again)."""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from enum import Enum

from stereopose.types import Event

__all__ = ["ENERGIZED", "ZONE_EVENTS", "Safe", "Safety", "made_safe"]

ENERGIZED = "energized"
# a person's events of a zone (never its state's own: zone_live, zone_dead, zone_unknown)
ZONE_EVENTS = ("enter", "approach", "dwell", "exit")


class Safety(str, Enum):  # noqa: UP042 (StrEnum would change str() of a member)
    """Why an energized zone is safe now: its event kind once made safe."""

    DEAD = "dead"  # switched out and earthed (its breakers' points)
    ISOLATED = "isolated"  # isolated by an active work ticket


@dataclass(frozen=True)
class Safe:
    """A zone safe now: why; source: the points that make it dead; ticket: the ticket that
    isolates it; types: the event types made safe (None: every event of the zone)."""

    why: Safety
    source: str | None = None
    ticket: str | None = None
    types: tuple[str, ...] | None = None

    @classmethod
    def dead(cls, source: str) -> Safe:
        return cls(Safety.DEAD, source=source, types=ZONE_EVENTS)

    @classmethod
    def isolated(cls, ticket: str) -> Safe:
        return cls(Safety.ISOLATED, ticket=ticket)

    def covers(self, e: Event) -> bool:
        return e.kind == ENERGIZED and (self.types is None or e.type in self.types)

    def apply(self, e: Event) -> Event:
        if self.why is Safety.DEAD:
            return dataclasses.replace(e, kind=self.why.value, source=self.source)
        return dataclasses.replace(e, kind=self.why.value, ticket=self.ticket)


def made_safe(events: Sequence[Event], judgements: Iterable[Mapping[str, Safe]]) -> list[Event]:
    """The events, each energized zone's that a judgement (zone -> Safe) holds safe rewritten
    as its Safe says; the judgements applied in order."""
    out = list(events)
    for safe in judgements:
        if safe:
            out = [
                safe[e.zone].apply(e) if e.zone in safe and safe[e.zone].covers(e) else e
                for e in out
            ]
    return out
