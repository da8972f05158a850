"""The events of one service step beyond the cameras' images: what FrameLoop's `fences` gives.

`ServeEvents.update(people3d)` returns, in order: on the first step the exits that close the
zones a killed run left occupied (service.restart), the zone events (fence), the camera events
(service.watch: camera_down / camera_up) and the calibration events (service.calib_health).
The service's source tells it which cameras delivered (`step`) and the step's 2D people
(`detected`), so the watch and the calibration's health see what the loop saw.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping

from stereopose.fence import FenceMonitor
from stereopose.io.sinks.base import FrameResult
from stereopose.pipeline.loop import SourceStep
from stereopose.service.calib_health import CalibrationHealth
from stereopose.service.watch import CameraWatch
from stereopose.types import Event, People2D, People3D


class ServeEvents:
    """See the module. fences: None without a site; calib: None to leave the calibration
    unwatched; opening(t, frame): the events of the first step (at its time and frame)."""

    def __init__(
        self,
        fences: FenceMonitor | None,
        watch: CameraWatch,
        calib: CalibrationHealth | None,
        opening: Callable[[float, int], list[Event]] | None = None,
    ) -> None:
        self.fences, self.watch, self.calib = fences, watch, calib
        self.opening = opening
        self._people2d: Mapping[str, People2D] = {}
        self._opened = False

    def step(self, step: SourceStep) -> None:
        """A step the source gives: each camera with an image delivered at its time."""
        self._people2d = {}
        for name, image in (step.images or {}).items():
            if image is not None and name in self.watch.cameras:
                self.watch.frame(name, step.t)

    def detected(self, people2d: Mapping[str, People2D]) -> None:
        self._people2d = people2d

    def update(self, people3d: People3D) -> list[Event]:
        t, frame = float(people3d.t or 0.0), int(people3d.frame)
        events: list[Event] = []
        if not self._opened:
            self._opened = True
            if self.opening is not None:
                events += self.opening(t, frame)
        if self.fences is not None:
            events += self.fences.update(people3d)
        events += self.watch.poll(t, frame)
        if self.calib is not None and len(people3d):
            events += self.calib.update(FrameResult(frame, t, self._people2d, people3d, []))
        return events
