"""What the service's health state answers (site.health.state.ServiceState.snapshot): the
whole service at one moment, each camera, queue and output, the stages' latency histograms."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Literal

from stereopose.site.health.alarm_outputs import OutputSnapshot

__all__ = ["CameraSnapshot", "HistogramSnapshot", "QueueSnapshot", "Snapshot"]


@dataclass(frozen=True)
class HistogramSnapshot:
    """A latency histogram: cumulative counts per upper bound (the last bound is +inf)."""

    bounds: tuple[float, ...]
    cumulative: tuple[int, ...]
    sum_s: float
    count: int


@dataclass(frozen=True)
class CameraSnapshot:
    """One camera: fps over its recent frames (0 while down), the age of its last frame in
    seconds (None: none yet), up when that age is within its timeout; nominal_fps: the rate it
    should be processed at (None: not known); processed_fps and dropped_share: over the last
    minute (None until judged: site.health.rates); slow: why it is processed badly (None: it
    is not)."""

    name: str
    fps: float
    last_frame_age_s: float | None
    up: bool
    frames: int
    reconnects: int
    dropped_frames: int
    timeout_s: float
    nominal_fps: float | None = None
    processed_fps: float | None = None
    dropped_share: float | None = None
    slow: str | None = None

    @property
    def state(self) -> Literal["up", "down"]:
        return "up" if self.up else "down"


@dataclass(frozen=True)
class QueueSnapshot:
    """One registered queue: its size now (None: its probe failed), messages dropped so far
    (None: not known), and whether it dropped within the last DROP_WINDOW_S."""

    name: str
    size: int | None
    dropped: int | None
    dropping: bool


@dataclass(frozen=True)
class Snapshot:
    """The whole state at one moment; see ServiceState."""

    version: str
    uptime_s: float
    frames: int
    people: int
    cameras: tuple[CameraSnapshot, ...]
    stages: Mapping[str, HistogramSnapshot]
    end_to_end: HistogramSnapshot
    events: Mapping[str, int]
    queues: tuple[QueueSnapshot, ...]
    storage: Mapping[str, int]
    problems: tuple[str, ...] = field(default=())
    outputs: tuple[OutputSnapshot, ...] = field(default=())
    # the alarm rates and open incidents (pipeline.incidents.IncidentStep.figures);
    # empty without an incident book
    alarms: Mapping[str, object] = field(default_factory=dict)
    # detection in regions by camera (detection.regional.CameraRegions.as_dict); empty: whole
    # frames, or the nodes detect
    regions: Mapping[str, Mapping[str, float]] = field(default_factory=dict)
    # each camera's light (detection.light.LightWatch.figures): mode, brightness, noise, ...
    light: Mapping[str, Mapping[str, object]] = field(default_factory=dict)

    @property
    def status(self) -> Literal["ok", "degraded", "down"]:
        """down: no camera delivering; degraded: a camera down or processed badly (far
        under its nominal rate, most of its frames dropped), the service stalled, a queue
        dropping, an alarm output failing or falling behind, or a probe failing; ok
        otherwise."""
        if not any(c.up for c in self.cameras):
            return "down"
        return "degraded" if self.problems else "ok"
