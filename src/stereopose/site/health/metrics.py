"""Prometheus metrics of the service, read from its ServiceState at each scrape.

Every app has its own CollectorRegistry (never the process-wide one), so several apps and the
tests do not collide. One collector turns one `ServiceState.snapshot()` into every metric
family, so a scrape is consistent with itself and with the health answer of the same moment.
Labels are cameras, stages, event types, queues, alarm outputs and storage kinds: bounded sets
(no person id). The version (stereopose_info) is shown to a scrape that carries a session;
an anonymous one reads version="" (the /metrics route sets VERSION_SHOWN for its scrape).
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from contextvars import ContextVar

from prometheus_client import CONTENT_TYPE_LATEST, CollectorRegistry, generate_latest
from prometheus_client.metrics_core import (
    CounterMetricFamily,
    GaugeMetricFamily,
    HistogramMetricFamily,
    Metric,
)
from prometheus_client.registry import Collector

from stereopose.detection.light import MODES
from stereopose.site.health.snapshots import HistogramSnapshot, Snapshot
from stereopose.site.health.state import ServiceState
from stereopose.types import JsonDoc

PREFIX = "stereopose_"
CONTENT_TYPE = CONTENT_TYPE_LATEST
# whether this scrape may see the version: set by the route around its one exposition
VERSION_SHOWN: ContextVar[bool] = ContextVar("stereopose_version_shown", default=True)


def _buckets(h: HistogramSnapshot) -> list[tuple[str, float]]:
    pairs = zip(h.bounds, h.cumulative, strict=True)
    return [("+Inf" if b == float("inf") else repr(b), c) for b, c in pairs]


def _counter(name: str, doc: str, label: str | None, values: dict[str, float]) -> Metric:
    family = CounterMetricFamily(PREFIX + name, doc, labels=[label] if label else None)
    for key, value in values.items():
        family.add_metric([key] if label else [], value)
    return family


def _gauge(name: str, doc: str, label: str | None, values: dict[str, float]) -> Metric:
    family = GaugeMetricFamily(PREFIX + name, doc, labels=[label] if label else None)
    for key, value in values.items():
        family.add_metric([key] if label else [], value)
    return family


def families(s: Snapshot, *, show_version: bool = True) -> Iterator[Metric]:
    """Every metric family of one snapshot (show_version False: version="")."""
    cams = s.cameras
    version = s.version if show_version else ""
    yield _gauge("info", "Version of the running service.", "version", {version: 1})
    yield _gauge("uptime_seconds", "Seconds since the service started.", None, {"": s.uptime_s})
    yield _counter("frames", "Frames processed.", None, {"": s.frames})
    yield _counter(
        "frames_dropped",
        "Frames dropped per camera.",
        "camera",
        {c.name: c.dropped_frames for c in cams},
    )
    yield _counter(
        "camera_reconnects",
        "Stream reconnects per camera.",
        "camera",
        {c.name: c.reconnects for c in cams},
    )
    yield _gauge(
        "camera_up",
        "1 while the camera delivers frames within its timeout.",
        "camera",
        {c.name: float(c.up) for c in cams},
    )
    yield _gauge(
        "camera_fps",
        "Frames per second over the camera's recent frames.",
        "camera",
        {c.name: c.fps for c in cams},
    )
    stages = HistogramMetricFamily(
        PREFIX + "stage_seconds", "Seconds per frame spent in each stage.", labels=["stage"]
    )
    for stage, h in s.stages.items():
        stages.add_metric([stage], _buckets(h), h.sum_s)
    yield stages
    e2e = HistogramMetricFamily(
        PREFIX + "end_to_end_latency_seconds", "Seconds from a frame's arrival to its outputs."
    )
    e2e.add_metric([], _buckets(s.end_to_end), s.end_to_end.sum_s)
    yield e2e
    yield _gauge("people", "People in the last frame.", None, {"": s.people})
    yield _counter(
        "events",
        "Events by type: zone, behaviour, camera, calibration and service events.",
        "type",
        dict(s.events),
    )
    yield _gauge(
        "queue_size",
        "Messages waiting per queue.",
        "queue",
        {q.name: q.size for q in s.queues if q.size is not None},
    )
    yield _counter(
        "queue_dropped",
        "Messages dropped per queue.",
        "queue",
        {q.name: q.dropped for q in s.queues if q.dropped is not None},
    )
    yield _gauge("storage_bytes", "Bytes stored per kind.", "kind", dict(s.storage))
    yield _gauge(
        "output_up",
        "1 while the alarm output delivers.",
        "output",
        {o.name: float(o.up) for o in s.outputs},
    )
    waiting: dict[str, float] = {o.name: o.waiting for o in s.outputs if o.waiting is not None}
    yield _gauge(
        "output_waiting", "Messages the alarm output holds, not delivered yet.", "output", waiting
    )
    yield _gauge(
        "output_backlog_seconds",
        "Seconds the alarm output has had messages waiting.",
        "output",
        {o.name: o.backlog_s for o in s.outputs},
    )
    if s.alarms:
        yield from _alarm_families(s.alarms)
    if s.regions:
        yield from _region_families(s.regions)
    yield from _light_families(s.light)


# detection in regions (detection.regional.CameraRegions): metric, figure, help
_REGIONS = (
    ("detection_steps", "steps", "Steps detected per camera."),
    ("detection_regions", "regions", "Regions cut and detected per camera."),
    (
        "detection_whole_frames",
        "whole_frames",
        "Steps a camera was detected in its whole frame "
        "(a scan, or regions that would cost more and see no finer).",
    ),
    (
        "detection_idle_steps",
        "idle_steps",
        "Steps a camera needed no inference: nobody tracked or seen, no motion, no scan due.",
    ),
    ("detection_full_scans", "full_scans", "Full scans of the camera's frame."),
    ("detection_input_pixels", "input_px", "Model input pixels detected per camera."),
    (
        "detection_whole_input_pixels",
        "whole_input_px",
        "Model input pixels whole frames at the detector's imgsz would have taken, per camera.",
    ),
    (
        "detection_newcomers_by_motion",
        "found_by_motion",
        "People found in a motion region where no track or earlier person was, per camera.",
    ),
    (
        "detection_newcomers_by_scan",
        "found_by_scan",
        "People found by a full scan where no track or earlier person was, per camera.",
    ),
)


def _region_families(regions: Mapping[str, JsonDoc]) -> Iterator[Metric]:
    """Detection in regions by camera: what it detected, against whole frames."""
    for name, key, doc in _REGIONS:
        yield _counter(
            name, doc, "camera", {cam: float(c.get(key, 0)) for cam, c in regions.items()}
        )


def _light_families(light: Mapping[str, JsonDoc]) -> Iterator[Metric]:
    """Each camera's light (detection.light): its mode, one of four, and the figures the
    mode rests on."""
    if not light:
        return
    family = GaugeMetricFamily(
        PREFIX + "camera_light",
        "1 for the camera's light now: day, night (its pictures prepared for the detector), "
        "black (nothing to see) or blinded.",
        labels=["camera", "mode"],
    )
    for cam, f in light.items():
        for mode in MODES:
            family.add_metric([cam, mode], float(f.get("mode") == mode))
    yield family
    for key, name, doc in (
        ("brightness", "camera_brightness", "Mean grey level (0-255) of the camera's picture."),
        ("noise", "camera_noise", "Sensor noise (grey levels, standard deviation)."),
        (
            "prepare_ms",
            "camera_night_prepare_ms",
            "Milliseconds a night picture's preparation took on average.",
        ),
    ):
        values = {cam: float(f[key]) for cam, f in light.items() if isinstance(f.get(key), float)}
        yield _gauge(name, doc, "camera", values)


def _alarm_families(a: JsonDoc) -> Iterator[Metric]:
    """The alarm rates (alarms.rates, ISA-18.2's figures) and the open incidents by priority
    and state (at most 4 x 3 label pairs)."""
    yield _gauge(
        "alarm_notifications",
        "Alarm notifications (new incidents not shelved) in the "
        "last window (10m, 1h); the flood line is 10 per 10 minutes.",
        "window",
        {"10m": float(a.get("notifications_10min", 0)), "1h": float(a.get("notifications_1h", 0))},
    )
    yield _gauge(
        "alarm_flood",
        "1 while notifications in the last 10 minutes exceed the flood line.",
        None,
        {"": float(bool(a.get("flood")))},
    )
    yield _gauge(
        "alarm_chattering",
        "Hazards notified 3 or more times in the last 60 s.",
        None,
        {"": float(a.get("chattering", 0))},
    )
    yield _gauge(
        "alarm_standing",
        "Incidents active for more than 24 h.",
        None,
        {"": float(a.get("standing", 0))},
    )
    yield _gauge(
        "alarm_shelved",
        "Open incidents shelved by an operator.",
        None,
        {"": float(a.get("shelved", 0))},
    )
    family = GaugeMetricFamily(
        PREFIX + "incidents_open",
        "Incidents not closed, by priority (1 critical .. 4 low) and state.",
        labels=["priority", "state"],
    )
    opened = a.get("open") or {}
    for key, n in sorted(opened.items()):
        priority, _, state = str(key).removeprefix("p").partition("_")
        family.add_metric([priority, state], float(n))
    yield family


class StateCollector(Collector):
    """Collects every family from one snapshot of `state` per scrape."""

    def __init__(self, state: ServiceState) -> None:
        self.state = state

    def collect(self) -> Iterator[Metric]:
        yield from families(self.state.snapshot(), show_version=VERSION_SHOWN.get())

    def describe(self) -> list[Metric]:
        return []  # nothing to check at registration; the names are fixed above


def make_registry(state: ServiceState) -> CollectorRegistry:
    """A registry of its own holding the collector of `state`."""
    registry = CollectorRegistry(auto_describe=False)
    registry.register(StateCollector(state))
    return registry


def exposition(registry: CollectorRegistry) -> bytes:
    """The registry in Prometheus text format."""
    return generate_latest(registry)
