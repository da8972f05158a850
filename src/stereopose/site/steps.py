"""The events of one service step beyond the cameras' images, and the people's time across a
stall of the service.

The service's chain of step rules (site.site_switch.site_rules, pipeline.step_rules) begins:
the exits that close the zones a killed run left occupied, at the first step (site.restart:
`OpeningEvents`), the zone events (the site's fence monitor on the people's time:
`HeldFences`), then the service's own events (`ServeEvents.update`: site.health.stall's
service_stalled / service_resumed, site.health.watch's camera_down / camera_up, and the
calibration's, site.health.calib_health and calib_keeper). The service's source tells
`ServeEvents` each step before the people's stages run (`step`: which cameras delivered, the
loop's beat) and the step's 2D people (`detected`).

A step with no frames (the source's heartbeat) is *held* when the service, not its cameras, is
late: a stall is in progress, or a camera's reader still has frames to give (`fresh`; a
recorded file always has). A held step is no observation: the people's stages skip it
(`HeldStage` gives the last people again, flagged predicted; `HeldRules` and `HeldFences`
nothing new), so a slow step does not make everybody vanish. After a stall, the people's stages
see the time without the stall's length: the people's time is its own object
(site.step_clock.StepClock, `ServeEvents.time`), moved here at each step and read by the held
stages.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING

import numpy as np

from stereopose.fence import FenceMonitor
from stereopose.io.sinks.base import FrameResult
from stereopose.pipeline.loop import SourceStep
from stereopose.site.health.calib_health import CalibrationHealth
from stereopose.site.health.calib_keeper import CalibrationKeeper
from stereopose.site.health.stall import StallWatch
from stereopose.site.health.watch import CameraWatch
from stereopose.site.step_clock import StepClock
from stereopose.types import Event, People2D, People3D

if TYPE_CHECKING:
    from stereopose.behaviour.rules import BehaviourMonitor
    from stereopose.pipeline.stage3d import Stage3D


@dataclasses.dataclass(frozen=True)
class StepHooks:
    """What the service gives the steps: opening(t, frame): the events of the first step (at
    its time and frame); fresh(camera): whether its reader still has frames to give (None:
    not known, only a stall holds steps); clock(): the service's time now, on the steps' clock
    (None: each step's t; a stopped process is seen only with it); on_stall(reason or None):
    told when a stall begins and ends; lost(camera): whether its stream is known lost (it
    ended, or its decoder died): the camera is down at the next step, not after the watch's
    timeout (None: not known)."""

    opening: Callable[[float, int], list[Event]] | None = None
    fresh: Callable[[str], bool] | None = None
    clock: Callable[[], float] | None = None
    on_stall: Callable[[str | None], None] | None = None
    lost: Callable[[str], bool] | None = None


class ServeEvents:
    """See the module. calib: None to leave the calibration unwatched; hooks: see StepHooks;
    stall: the service's stall watch (default: on the watch's timeout); keeper: the
    calibration keeper (site.health.calib_keeper; None: drift only flagged); opening: the
    chain's first rule's events (OpeningEvents)."""

    def __init__(
        self,
        watch: CameraWatch,
        calib: CalibrationHealth | None,
        hooks: StepHooks = StepHooks(),
        *,
        stall: StallWatch | None = None,
        keeper: CalibrationKeeper | None = None,
    ) -> None:
        self.watch, self.calib = watch, calib
        self.keeper = keeper  # a drifted camera placed again
        self.opening = OpeningEvents(hooks.opening)  # the first rule of the chain
        self.stall = stall or StallWatch(watch.timeout_s)
        self.fresh, self.clock, self.on_stall = hooks.fresh, hooks.clock, hooks.on_stall
        self.lost = hooks.lost
        self.time = StepClock(self.stall)  # the people's time, read by HeldStage and HeldRules
        self._people2d: Mapping[str, People2D] = {}
        self._t = 0.0
        self._delivered_t: float | None = None  # the last step with frames
        self._people_t = -math.inf  # the people's time of the last step they saw

    @property
    def held(self) -> bool:
        """This step is no observation (see the module)."""
        return self.time.held

    @property
    def held_s(self) -> float:
        """Seconds the people's stages leave out so far (their time is t - held_s)."""
        return self.time.held_s

    # -- the step, before the people's stages ------------------------------------------------

    def step(self, step: SourceStep) -> None:
        """A step the source gives: each camera with an image delivered at its time."""
        self._people2d = {}
        t, self._t = float(step.t), float(step.t)
        now = max(t, float(self.clock())) if self.clock is not None else t
        delivered = [
            name
            for name, image in (step.images or {}).items()
            if image is not None and name in self.watch.cameras
        ]
        stall = self.stall
        if stall.beat(now, step.frame):
            self._began()
        if not delivered and not stall.stalled and self._all_late(t):
            # no step with frames since the last one that had some, or since the watch began
            since = self._delivered_t if self._delivered_t is not None else self.watch.start
            stall.late(now, since)
            self._began()
        # the stall ends with frames read after it began (a step read before a pause is stale),
        # or, timeout_s on, with no reader delivering: then it is the cameras'
        fresh_frames = bool(delivered) and t > (stall.fresh_after or 0.0)
        if stall.stalled and (fresh_frames or self._blind_after_stall(now)):
            length = stall.resume(t, now, most=t - stall.held_s - self._people_t - 1e-3) or 0.0
            self.time.resumed(t)
            if delivered:  # the stall is not the cameras' silence
                self.watch.shift(length)
            if self.on_stall is not None:
                self.on_stall(None)
        for name in delivered:
            self.watch.frame(name, t)
        if self.lost is not None:
            for name in self.watch.cameras:
                if name not in delivered and self.lost(name):
                    self.watch.lost(name)
        if delivered:
            self._delivered_t = t
        self.time.held = not delivered and (stall.stalled or self._any_fresh())
        if not self.time.held:
            self._people_t = self.time.people_t(t)

    def _began(self) -> None:
        if self.on_stall is not None:
            self.on_stall(f"stalled since {self.stall.onset_t:.1f} s")

    def _all_late(self, t: float) -> bool:
        """Every camera not down is overdue at t, and their readers deliver (unknown: at
        least two of them at once)."""
        due, up = self.watch.overdue(t), self.watch.up()
        if not due or set(due) != set(up):
            return False
        if self.fresh is None:
            return len(due) >= 2
        return all(self.fresh(name) for name in due)

    def _blind_after_stall(self, now: float) -> bool:
        """A stall that has lasted timeout_s more with no reader delivering is the cameras':
        it ends, and the watch takes them down."""
        declared = self.stall.declared_t
        if declared is None or now - declared <= self.watch.timeout_s:
            return False
        return not self._any_fresh()

    def _any_fresh(self) -> bool:
        return self.fresh is not None and any(self.fresh(n) for n in self.watch.cameras)

    def detected(self, people2d: Mapping[str, People2D]) -> None:
        self._people2d = people2d

    # -- the events, after the 3D stage --------------------------------------------------------

    def update(self, people3d: People3D) -> list[Event]:
        """The service's, the cameras' and the calibration's events of the step."""
        t, frame = self._t, int(people3d.frame)
        events = self.stall.events()
        if not self.stall.stalled:
            events += self.watch.poll(t, frame)
        if self.calib is not None and not self.held and len(people3d):
            drift = self.calib.update(FrameResult(frame, t, self._people2d, people3d, []))
            events += drift
        else:
            drift = []
        if self.keeper is not None and not self.held:
            events += self.keeper.update(frame, t, self._people2d, drift)
        return events


class OpeningEvents:
    """The events of the service's first step (`opening(t, frame)`: the exits that close the
    zones a killed run left occupied, site.restart), none after; None: none at all."""

    def __init__(self, opening: Callable[[float, int], list[Event]] | None) -> None:
        self.opening = opening
        self._opened = False

    def update(self, people3d: People3D) -> list[Event]:
        if self._opened:
            return []
        self._opened = True
        if self.opening is None:
            return []
        return self.opening(float(people3d.t or 0.0), int(people3d.frame))


class HeldFences:
    """The site's fence monitor (fence.FenceMonitor) on the people's time `time`: a held step
    gives no zone event; the others' events are stamped on the service's clock."""

    def __init__(self, monitor: FenceMonitor, time: StepClock) -> None:
        self.monitor, self.time = monitor, time

    def update(self, people3d: People3D) -> list[Event]:
        if self.time.held:
            return []
        t_people = self.time.people_t(float(people3d.t or 0.0))
        return self.time.restamp(self.monitor.update(people3d.at(t_people)))


class HeldStage:
    """The 3D stage (pipeline.stage3d.Stage3D) on the people's time `time`: a held step gives
    the last people again (flagged predicted, stamped with the step); others are computed at
    t - held_s and stamped with t."""

    def __init__(self, inner: Stage3D, time: StepClock) -> None:
        self.inner, self.time = inner, time
        self.tracking = inner.tracking
        self._last: People3D | None = None

    def load(self) -> float:
        return self.inner.load()

    def trajectories(self) -> list:
        return self.inner.trajectories()

    def step(
        self, frame: int, people2d: Mapping[str, People2D], t: float | None = None
    ) -> People3D:
        t = float(frame / self.inner.fps if t is None else t)
        last = self._last
        if self.time.held and last is not None:
            held = np.ones(len(last), dtype=bool)
            return dataclasses.replace(last, frame=frame, predicted=held, t=t)
        people = self.inner.step(frame, people2d, self.time.people_t(t)).at(t)
        self._last = people
        return people


class HeldRules:
    """The behaviour rules (behaviour.rules.BehaviourMonitor) on the people's time `time`: a
    held step raises nothing and keeps the last postures."""

    def __init__(self, inner: BehaviourMonitor, time: StepClock) -> None:
        self.inner, self.time = inner, time
        self._postures: dict = {}

    def step(self, t: float, frame: int, people: People3D) -> tuple[list[Event], dict]:
        if self.time.held:
            return [], self._postures
        t_people = self.time.people_t(float(t))
        found, self._postures = self.inner.step(t_people, frame, people.at(t_people))
        return self.time.restamp(found), self._postures
