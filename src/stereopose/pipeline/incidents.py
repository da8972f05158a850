"""The service's incidents: every step's events through the incident book before any sink.

`IncidentStep` is a step's rules of the frame loop (pipeline.loop.StepRules): its
`step(t, frame, people)` takes the events of the step's rules (pipeline.step_rules.StepChain:
the zone, camera and service events, the behaviour's, the zones' states', the tickets'), and
hands them all, in order, to the book
(stereopose.alarms.IncidentBook), with the pairs the fence still holds (inside or at the
margin). Each event reaches the sinks with its `incident` and `priority` (both None for an
info-level event: it belongs to no incident, and its priority is not an alarm's).

Each change of an incident (raised, occurrence, cleared, acknowledged, shelved, ...) is handed
to every `outputs` callable (the alarm outputs' write_changes: the event log, stored in the
step's transaction, MQTT, the webhook, SCADA; the live channel) before the step's events reach
the sinks. An operator's act (the HTTP API's thread) takes the lock around the book and answers
at once with the record; its changes wait (bounded, counted when dropped) and go out with the
next step, which comes within the loop's heartbeat.

What a step holds of its site is one object (`SiteRules`: the chain of rules, the fence monitor
that says which pairs hold, the alarm settings). A new site is a new `SiteRules`, built by
`switch` at a step's start (site.site_switch) and taken whole (`take`) before the step's rules
run; the book carries its open incidents across, on the new settings.
"""

from __future__ import annotations

import dataclasses
import logging
import threading
from collections import deque
from collections.abc import Callable, Sequence

import numpy as np

from stereopose.alarms import AlarmRates, Change, IncidentBook, IncidentRecord
from stereopose.alarms.incident import IncidentError
from stereopose.alarms.priority import AlarmSettings
from stereopose.fence.rules import FenceMonitor
from stereopose.io.sinks.incidents import IncidentIds
from stereopose.pipeline.step_rules import StepChain
from stereopose.types import Event, People3D

__all__ = ["IncidentStep", "SiteRules", "SiteSwitching"]

logger = logging.getLogger(__name__)

MAX_WAITING = 10_000  # operators' changes waiting for the next step


@dataclasses.dataclass(frozen=True)
class SiteRules:
    """A site's part of the step: its chain of rules; the fence monitor that says which
    (zone, person) pairs still hold (None: no site); its alarm settings (None: the book's
    own, as built)."""

    chain: StepChain
    holding: FenceMonitor | None = None
    settings: AlarmSettings | None = None


# at a step's start, before its rules: (the events of a change of site, the new site's rules
# to take, or None: no new site); given the site's rules in force, the step's t and frame
SiteSwitching = Callable[[SiteRules, float, int], tuple[list[Event], SiteRules | None]]


class IncidentStep:
    """See the module. chain: the step's rules (pipeline.step_rules.StepChain: fences,
    behaviour, zone state, tickets); holding: the fence monitor that says which (zone, person)
    pairs still hold, or None; outputs: callables given each step's changes, in order (the
    event log's write_changes first: its records stored in the step's transaction); clock():
    the service's time now (the events' clock)."""

    def __init__(
        self,
        book: IncidentBook,
        chain: StepChain,
        *,
        holding: FenceMonitor | None = None,
        outputs: Sequence[Callable[[Sequence[Change]], None]] = (),
        clock: Callable[[], float],
        wall_start: float | None = None,
        switch: SiteSwitching | None = None,
    ) -> None:
        self.book = book
        self.rules = SiteRules(chain, holding)
        self.switch = switch
        self.wall_start = wall_start  # Unix time of t = 0: the changes carry wall times
        self.outputs, self.clock = list(outputs), clock
        self.rates = AlarmRates()
        self.lock = threading.Lock()
        self.waiting: deque[Change] = deque()
        self.dropped = 0  # operators' changes dropped (the queue full): counted, logged

    # -- the frame loop's: a step's rules (pipeline.loop.StepRules)
    @property
    def chain(self) -> StepChain:
        return self.rules.chain

    @property
    def monitor(self) -> FenceMonitor | None:
        return self.rules.holding

    def take(self, rules: SiteRules) -> None:
        """A new site's rules, taken whole between two steps; the book keeps its incidents."""
        with self.lock:
            if rules.settings is not None:
                self.book.retune(rules.settings)
            self.rules = rules

    def step(self, t: float, frame: int, people: People3D) -> tuple[list[Event], dict | None]:
        """The chain's events, each alarm-level one stamped with its incident; the postures."""
        first: list[Event] = []
        if self.switch is not None:
            first, taken = self.switch(self.rules, t, frame)
            if taken is not None:
                self.take(taken)
        events, postures = self.chain.step(t, frame, people)
        return self._book(t, [*first, *events]), postures

    def finish(self, t: float, frame: int) -> list[Event]:
        """The events of the input's end at its last step (every active ticket completed),
        through the book like a step's."""
        events = self.chain.finish(t, frame)
        return self._book(t, events) if events else []

    @property
    def ends_with_source(self) -> bool:
        """Whether the end of the input ends something (a ticket active to the last frame)."""
        return self.chain.ends_with_source

    def _book(self, t: float, events: list[Event]) -> list[Event]:
        """The events through the book, each alarm-level one stamped with its incident."""
        ids = self.book.next_id
        if isinstance(ids, IncidentIds):  # reserved ahead: the book never waits for the log
            ids.top_up()
        with self.lock:
            now = max(float(t), *(e.t for e in events)) if events else float(t)
            up = self.book.update(events, now, holding=self._holding())
            changes = [*self.waiting, *up.changes]
            self.waiting.clear()
            out = [self._stamped(e, i) for e, i in zip(events, up.incidents, strict=True)]
        self._publish(changes)
        return out

    def _stamped(self, e: Event, incident: int | None) -> Event:
        if incident is None:
            return e
        try:
            priority = self.book.get(incident).priority
        except IncidentError:  # dropped from a full book within the step
            priority = None
        return dataclasses.replace(e, incident=incident, priority=priority)

    def _holding(self) -> set[tuple[str, int]] | None:
        mon = self.monitor
        if mon is None:
            return None
        rows, ks = np.nonzero(mon.inside.state | mon.near.state)
        return {(mon.zones[k].name, int(mon.ids[r])) for r, k in zip(rows, ks, strict=True)}

    def _publish(self, changes: Sequence[Change]) -> None:
        if not changes:
            return
        if self.wall_start is not None:
            changes = [dataclasses.replace(c, wall_start=self.wall_start) for c in changes]
        self.rates.observe(changes)
        for out in self.outputs:
            try:
                out(changes)
            except Exception as e:  # one output failing never stops the others or the loop
                logger.warning("incidents: an output failed: %s", e)

    # -- an operator's acts (any thread)
    def _act(self, act: Callable[[float], list[Change]], incident_id: int) -> IncidentRecord:
        with self.lock:
            changes = act(float(self.clock()))
            if len(self.waiting) + len(changes) > MAX_WAITING:
                self.dropped += len(changes)
                logger.error("incidents: %d change(s) dropped (the queue is full)", len(changes))
            else:
                self.waiting.extend(changes)
            return self.book.get(incident_id)

    def acknowledge(self, incident_id: int, by: str) -> IncidentRecord:
        """UnknownIncidentError for an id the book does not hold."""
        return self._act(lambda now: self.book.acknowledge(incident_id, by, now), incident_id)

    def shelve(self, incident_id: int, by: str, reason: str, duration_s: float) -> IncidentRecord:
        """UnknownIncidentError for an unknown id, IncidentError for a bad shelving."""
        return self._act(
            lambda now: self.book.shelve(incident_id, by, reason, duration_s, now), incident_id
        )

    def figures(self) -> dict:
        """The alarm rates (alarms.rates) and the open incidents by priority and state."""
        with self.lock:
            records = self.book.incidents()
            now = float(self.clock())
            doc = self.rates.figures(now, records).to_dict()
        by: dict[str, int] = {}
        shelved = 0
        for r in records:
            if r.state != "closed":
                name = f"p{r.priority}_{r.state}"
                by[name] = by.get(name, 0) + 1
                shelved += r.shelved
        doc["open"] = by
        doc["shelved"] = shelved
        doc["operator_changes_dropped"] = self.dropped
        return doc
