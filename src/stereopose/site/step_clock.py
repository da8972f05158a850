"""The people's time across stalls of the service: what the 3D stage and the behaviour rules
see, and how their events' times go back on the service's clock.

A step is *held* when it is no observation (the service, not its cameras, was late: see
site.steps): the people's stages skip it. After a stall they see the time without the stall's
length (`held_s`, from the stall watch), so tracks, zone occupancy and behaviour states go on
as if the service had not paused; `to_wall` and `restamp` put their events' times back on the
service's clock. `ServeEvents` (site.steps) moves the clock at each step; `HeldStage` and
`HeldRules` read it.
"""

from __future__ import annotations

import dataclasses
from collections import deque

from stereopose.site.health.stall import StallWatch
from stereopose.types import Event

MAX_BREAKS = 64  # stalls remembered to put older onsets back on the clock (bounded)


class StepClock:
    """The people's time of the service's steps: `held` (this step is no observation),
    `held_s` (seconds the people's stages leave out so far: their time is t - held_s),
    `resumed(t)` when a stall ends at step time t."""

    def __init__(self, stall: StallWatch) -> None:
        self.stall = stall
        self.held = False
        # (the people's time where a stall's hold began, held seconds from then on)
        self._breaks: deque[tuple[float, float]] = deque(maxlen=MAX_BREAKS)

    @property
    def held_s(self) -> float:
        return self.stall.held_s

    def people_t(self, t: float) -> float:
        """Step time t on the people's clock."""
        return t - self.stall.held_s

    def resumed(self, t: float) -> None:
        """A stall ended at step time t (its length now in held_s)."""
        self._breaks.append((t - self.stall.held_s, self.stall.held_s))

    def to_wall(self, t_people: float) -> float:
        """A time of the people's stages on the service's clock (before the stalls since)."""
        held = 0.0
        for start, total in self._breaks:
            if t_people >= start:
                held = total
        return t_people + held

    def restamp(self, events: list[Event]) -> list[Event]:
        """Events of the people's stages with their times on the service's clock."""
        if not self._breaks:
            return events
        return [
            dataclasses.replace(e, t=self.to_wall(e.t), onset_t=self.to_wall(e.onset_t))
            for e in events
        ]
