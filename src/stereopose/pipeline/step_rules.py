"""One chain of step rules, built alike by `run` and `serve`: at each step the fences, the
behaviour rules, the zones' live or dead state, the work tickets and (serve) the warnings on
site, in that order, each a
`StepRule` with one typed interface. Each adds its events to the step's; those that know a zone
safe now (dead by its breakers, isolated by a ticket) say so, and the chain makes that zone's
events information in one place (zones.safe), before the incident book sees them
(pipeline.incidents).

A chain is a step's rules of the frame loop on its own (pipeline.loop.StepRules: no incident
book), or the first half of an IncidentStep. Its rules are a list: a new site is swapped in at a
step boundary by building the chain again.

What one rule gives the rules after it is declared, not left to the order: a rule names what
it fills in the step's context (`gives`: the behaviour rule, the postures) and what it reads
there (`reads`: the tickets, the postures), and a chain refuses an order in which a rule reads
what a later rule gives.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, ClassVar, Protocol, runtime_checkable

from stereopose.fence.rules import FenceMonitor
from stereopose.tickets import TicketDesk
from stereopose.types import Event, People3D
from stereopose.zones.power_state import ZoneStates
from stereopose.zones.safe import Safe, made_safe
from stereopose.zones.state_log import ZoneStateLog

if TYPE_CHECKING:
    from stereopose.behaviour.posture import Posture

__all__ = [
    "BehaviourRule",
    "EventsRule",
    "FenceRule",
    "OnSiteRule",
    "StepChain",
    "StepContext",
    "StepRule",
    "TicketRule",
    "ZoneStateRule",
    "step_chain",
]


@dataclass
class StepContext:
    """What a step's rules share: its time, frame and people; the postures once the behaviour
    rule has classified them (None: no posture rules); the events of the rules before."""

    t: float
    frame: int
    people: People3D
    postures: dict[int, Posture] | None = None  # given by BehaviourRule, read by TicketRule
    events: list[Event] = field(default_factory=list)


class StepRule(Protocol):
    """One rule of the step: `step(ctx)` returns its events; a rule that fills a field of ctx
    for the rules after it names it in `gives`, one that reads such a field in `reads` (the
    class attributes, empty where not set)."""

    def step(self, ctx: StepContext) -> list[Event]: ...


@runtime_checkable
class SafetyRule(Protocol):
    """A rule that knows which zones are safe now (zone -> Safe), after its step."""

    def safe_now(self) -> Mapping[str, Safe]: ...


class ZoneEvents(Protocol):
    """Events of a step from its people: FenceMonitor, the service's held one
    (site.steps.HeldFences), or the service's own (site.steps.ServeEvents, OpeningEvents)."""

    def update(self, people: People3D, /) -> Sequence[Event]: ...


class ServiceEvents(ZoneEvents, Protocol):
    """The service's own events (site.steps.ServeEvents): those of its first step
    (`opening`, before the fences'), and each step's (`update`, after the fences')."""

    @property
    def opening(self) -> ZoneEvents: ...


class Behaviour(Protocol):
    """behaviour.rules.BehaviourMonitor, or the service's held one (site.steps.HeldRules)."""

    def step(
        self, t: float, frame: int, people: People3D
    ) -> tuple[list[Event], dict[int, Posture]]: ...


class EventsRule:
    """The events `events.update(people)` gives at each step (the service's own: site.steps)."""

    def __init__(self, events: ZoneEvents) -> None:
        self.events = events

    def step(self, ctx: StepContext) -> list[Event]:
        return list(self.events.update(ctx.people))


class FenceRule(EventsRule):
    """The zones' events (enter, approach, dwell, exit) of the fence monitor `events`."""


class BehaviourRule:
    """The behaviour rules' events; the postures for the rules after it and the sinks."""

    gives: ClassVar[frozenset[str]] = frozenset({"postures"})

    def __init__(self, behaviour: Behaviour) -> None:
        self.behaviour = behaviour

    def step(self, ctx: StepContext) -> list[Event]:
        events, ctx.postures = self.behaviour.step(ctx.t, ctx.frame, ctx.people)
        return list(events)


class ZoneStateRule:
    """The energized zones' states from their breakers (zone_live, zone_dead, zone_unknown);
    someone inside a zone that turns live (the fence monitor's) is an alarm at once."""

    def __init__(self, states: ZoneStates, monitor: FenceMonitor | None) -> None:
        self.states, self.monitor = states, monitor

    def step(self, ctx: StepContext) -> list[Event]:
        return list(self.states.step(ctx.t, ctx.frame, self.monitor))

    def safe_now(self) -> Mapping[str, Safe]:
        return self.states.safe_now()


class TicketRule:
    """The active work tickets' events (their steps, supervisor, lone worker); a step done in
    a posture reads the behaviour rule's postures (None without it)."""

    reads: ClassVar[frozenset[str]] = frozenset({"postures"})

    def __init__(self, desk: TicketDesk) -> None:
        self.desk = desk

    def step(self, ctx: StepContext) -> list[Event]:
        return list(self.desk.step(ctx.t, ctx.frame, ctx.people, ctx.postures))

    def safe_now(self) -> Mapping[str, Safe]:
        return self.desk.safe_now()

    def finish(self, t: float, frame: int) -> list[Event]:
        return self.desk.finish(t, frame)

    @property
    def ends_with_source(self) -> bool:
        return bool(self.desk.active_or_starting())


class OnSite(Protocol):
    """onsite.service.OnSite: the step's hazards said and shown on site."""

    def step(
        self,
        t: float,
        frame: int,
        people: People3D,
        fences: FenceMonitor | None,
        events: Sequence[Event] = (),
    ) -> list[Event]: ...


class OnSiteRule:
    """The warnings on site (speakers, beacons) from the fences' state at this step, and the
    calls of the events before it (a person down, a ticket's step in the wrong position);
    their devices' health events and the admin's acts. Last: the zones' states and the tickets
    are known by then."""

    def __init__(self, onsite: OnSite, fences: FenceMonitor | None) -> None:
        self.onsite, self.fences = onsite, fences

    def step(self, ctx: StepContext) -> list[Event]:
        return list(self.onsite.step(ctx.t, ctx.frame, ctx.people, self.fences, ctx.events))


class StepChain:
    """The step's rules in order (see the module); a step's rules of the frame loop."""

    def __init__(self, rules: Sequence[StepRule]) -> None:
        self.rules = list(rules)
        for k, rule in enumerate(self.rules):
            later = {f for r in self.rules[k + 1 :] for f in _declared(r, "gives")}
            if _declared(rule, "reads") & later:
                raise ValueError(
                    f"{type(rule).__name__} reads {sorted(_declared(rule, 'reads') & later)} "
                    "that a rule after it gives: it must come after that rule"
                )
        self._safety = [r for r in self.rules if isinstance(r, SafetyRule)]  # looked up once

    def step(
        self, t: float, frame: int, people: People3D
    ) -> tuple[list[Event], dict[int, Posture] | None]:
        """The step's events, every rule's in order, each safe zone's made information; the
        postures."""
        ctx = StepContext(float(t), int(frame), people)
        events = ctx.events  # each rule's added: the rules after it see them
        for rule in self.rules:
            events += rule.step(ctx)
        return made_safe(events, [r.safe_now() for r in self._safety]), ctx.postures

    def finish(self, t: float, frame: int) -> list[Event]:
        """The events of the input's end at its last step (every active ticket completed)."""
        return [e for r in self.rules if isinstance(r, TicketRule) for e in r.finish(t, frame)]

    @property
    def ends_with_source(self) -> bool:
        """Whether the end of the input ends something (a ticket active to the last frame)."""
        return any(isinstance(r, TicketRule) and r.ends_with_source for r in self.rules)


def _declared(rule: object, which: str) -> frozenset[str]:
    """A rule's `gives` or `reads` (empty where it declares none)."""
    own = (vars(c)[which] for c in type(rule).__mro__ if which in vars(c))
    return frozenset(next(own, ()))


def step_chain(
    events: ZoneEvents | None,
    *,
    service: ServiceEvents | None = None,
    behaviour: Behaviour | None = None,
    zone_state: ZoneStates | None = None,
    monitor: FenceMonitor | None = None,
    tickets: TicketDesk | None = None,
    zone_log: ZoneStateLog | None = None,
    onsite: OnSite | None = None,
) -> StepChain:
    """The chain `run` and `serve` build: the service's opening events (its first step's:
    `service.opening`), the fences' `events`, the service's own (`service`: its stalls,
    cameras, calibration), the behaviour rules, the zones' states (read live, with the fence
    `monitor` that says who is inside; or a recorded job's switching log, zones.state_log),
    the tickets, the warnings on site (`onsite`, with the fence `monitor`); each left out
    when None."""
    rules: list[StepRule] = []
    if service is not None:
        rules.append(EventsRule(service.opening))
    if events is not None:
        rules.append(FenceRule(events))
    if service is not None:
        rules.append(EventsRule(service))
    if behaviour is not None:
        rules.append(BehaviourRule(behaviour))
    if zone_state is not None:
        rules.append(ZoneStateRule(zone_state, monitor))
    if zone_log is not None:
        rules.append(zone_log)
    if tickets is not None:
        rules.append(TicketRule(tickets))
    if onsite is not None:
        rules.append(OnSiteRule(onsite, monitor))
    return StepChain(rules)
