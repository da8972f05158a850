"""A stall of the whole service: every camera late at once because the service itself is late.

A loaded machine (or a process paused by the system) makes every camera look silent at the same
moment although none of them is: the frame loop did not run, or no step brought frames for
longer than the camera timeout while the cameras' readers still had frames to give. That is one
fault of the service, not one per camera, and nobody left the site meanwhile:

    stall = StallWatch(timeout_s=config.serve.camera_timeout_s)
    stall.beat(now)                    # each loop step, before the people's stages
    stall.late(now, onset_t)           # no step with frames since onset_t, readers delivering
    stall.resume(t, now)               # the first step with frames read after it was seen
    events = stall.events()            # service_stalled, then service_resumed

`beat` declares a stall when the loop itself did not run for longer than timeout_s (on the
service's clock `now`, monotonic: it goes on while the process is stopped). `late` declares one
when the caller finds every camera overdue together (site.health.watch.CameraWatch.overdue).
While a stall lasts the camera watch raises no camera_down. Its length, but the first KEPT_S
seconds, is added to `held_s`: the time the people's stages leave out (the tracker's prediction
and max_lost_s, the fences' and the behaviour rules' lost_s), so a stall ends no track. Events:
kind "service", zone "", person -1; service_stalled (onset_t: the last step before the stall,
duration_s: how late it was when seen) and service_resumed (duration_s: the whole stall). Times
are seconds on the service's clock (the steps' t).
"""

from __future__ import annotations

import logging
import math
from typing import Unpack

from stereopose.types import Event, EventFields

__all__ = ["KEPT_S", "SERVICE_KIND", "StallWatch", "service_event"]

logger = logging.getLogger(__name__)

SERVICE_KIND = "service"
KEPT_S = 1.0  # of a stall, the seconds the people's ageing still counts (prediction, re-id reach)


def service_event(
    kind_of_event: str, t: float, frame: int, onset_t: float, **fields: Unpack[EventFields]
) -> Event:
    """An event about the service itself (kind "service", zone "", person -1)."""
    return Event(
        t=t,
        frame=frame,
        person=-1,
        zone="",
        kind=SERVICE_KIND,
        type=kind_of_event,
        onset_t=onset_t,
        **fields,
    )


class StallWatch:
    """See the module. timeout_s (> 0): the cameras' timeout; kept_s (>= 0): see KEPT_S."""

    def __init__(self, timeout_s: float, *, kept_s: float = KEPT_S) -> None:
        if not (timeout_s > 0 and math.isfinite(timeout_s)):
            raise ValueError(f"timeout_s must be a positive number of seconds, got {timeout_s}")
        if not (kept_s >= 0 and math.isfinite(kept_s)):
            raise ValueError(f"kept_s must be a number of seconds >= 0, got {kept_s}")
        self.timeout_s, self.kept_s = float(timeout_s), float(kept_s)
        self.held_s = 0.0  # seconds of stalls the people's stages leave out, so far
        self.stalls = 0
        self.onset_t: float | None = None  # the stall in progress: its last step before
        self.declared_t: float | None = None  # when it was seen
        self.fresh_after: float | None = None  # a step read after this ends it
        self._beat_at: float | None = None  # monotonic time of the loop's last step
        self._frame = 0
        self._events: list[Event] = []

    @property
    def stalled(self) -> bool:
        return self.onset_t is not None

    def beat(self, now: float, frame: int = 0) -> bool:
        """A loop step at `now` (the service's clock read as the step begins, which goes on
        while the process is stopped); whether the gap since the last step (the loop not
        running) declared a stall."""
        onset = self._beat_at
        self._beat_at, self._frame = float(now), int(frame)
        if self.stalled or onset is None or now - onset <= self.timeout_s:
            return False
        # frames read before the pause may still come after it: the fresh ones are nearer its end
        self._declare(
            now,
            onset,
            f"the frame loop did not run for {now - onset:.1f} s",
            fresh_after=(onset + now) / 2,
        )
        return True

    def late(self, now: float, onset_t: float) -> bool:
        """Every camera overdue at `now`, no step with frames since onset_t, while their
        readers still deliver: a stall (unless one is in progress); whether it was declared."""
        if self.stalled:
            return False
        self._declare(now, onset_t, f"no step for {now - onset_t:.1f} s, every camera at once")
        return True

    def resume(self, t: float, now: float | None = None, most: float | None = None) -> float | None:
        """The first step with frames read after a stall began (t > fresh_after: frames read
        before a pause can come after it), at `now` (None: t); the stall's length (None: none
        in progress). Its length but kept_s (at most `most`) is added to held_s."""
        if self.onset_t is None:
            return None
        now = float(t) if now is None else float(now)
        length = max(0.0, float(t) - self.onset_t)
        held = max(0.0, length - self.kept_s)
        self.held_s += held if most is None else min(held, max(0.0, most))
        self._events.append(
            service_event("service_resumed", now, self._frame, self.onset_t, duration_s=length)
        )
        logger.warning("service: resumed after a stall of %.1f s", length)
        self.onset_t = None
        return length

    def events(self) -> list[Event]:
        """The service events since the last call, in order."""
        out, self._events = self._events, []
        return out

    def _declare(
        self, now: float, onset_t: float, why: str, fresh_after: float | None = None
    ) -> None:
        self.onset_t = float(onset_t)
        self.declared_t = float(now)
        self.fresh_after = self.onset_t if fresh_after is None else float(fresh_after)
        self.stalls += 1
        self._events.append(
            service_event(
                "service_stalled",
                now,
                self._frame,
                self.onset_t,
                duration_s=max(0.0, now - self.onset_t),
            )
        )
        logger.error("service stalled: %s (the machine is overloaded or was paused)", why)
