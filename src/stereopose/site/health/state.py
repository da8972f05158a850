"""What the running service knows about itself, for health and metrics.

The frame loop and the camera readers write (`camera_frame`, `on_frame`, `on_events`, ...);
the HTTP side only reads `snapshot()`, a frozen copy taken under one lock, so a health answer
and a metrics scrape each see one consistent moment. Memory is bounded whatever runs for how
long: per camera a fixed window of arrival times, per stage a fixed set of histogram buckets,
and a cap on the number of cameras, stages, event types, queues and outputs (names beyond it
are counted under no new label, with one warning).

A camera is also degraded while the service keeps up with it badly over the last minute
(site.health.rates.CameraRates): it is processed under half of its nominal rate (its frame
rate, or [input] detect_fps; `add_camera(name, nominal_fps=...)`), or most of its frames are
dropped (beyond those a lower nominal rate leaves out). A stall of the whole service
(site.health.stall) is a problem while it lasts (`service_stall`).

Alarm outputs (MQTT, the webhook, the event log, SCADA links: io.sinks.health) are registered
with `register_output`: the service is degraded while one is not ok, or while one has had
messages waiting at every read for BACKLOG_S (it takes them more slowly than they come).

Times are seconds on `clock` (time.monotonic by default); arrival times given to the state
must be on the same clock.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections import deque
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from itertools import pairwise

from stereopose import __version__
from stereopose.io.sinks.base import FrameResult
from stereopose.site.health.alarm_outputs import OutputProbe, OutputWatch
from stereopose.site.health.rates import CameraRates
from stereopose.site.health.snapshots import (
    CameraSnapshot,
    HistogramSnapshot,
    QueueSnapshot,
    Snapshot,
)
from stereopose.types import Event

logger = logging.getLogger(__name__)

# Latency buckets in seconds: from one fast stage (1 ms) to a stalled frame (10 s).
LATENCY_BUCKETS_S = (0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 5.0, 10.0)
MAX_NAMES = 64  # cameras, stages, event types, queues: each at most this many names
FPS_WINDOW = 32  # arrival times kept per camera for its frame rate
DROP_WINDOW_S = 60.0  # a queue that dropped within this long makes the service degraded

QueueProbe = Callable[[], int]
StorageProbe = Callable[[], Mapping[str, int]]


class _Histogram:
    """Fixed buckets, counted in place: no list grows with the number of observations."""

    def __init__(self, bounds: Sequence[float]) -> None:
        self.bounds = (*bounds, math.inf)
        self.counts = [0] * len(self.bounds)
        self.sum_s = 0.0

    def observe(self, seconds: float) -> None:
        for i, bound in enumerate(self.bounds):
            if seconds <= bound:
                self.counts[i] += 1
                break
        self.sum_s += seconds

    def snapshot(self) -> HistogramSnapshot:
        cumulative, total = [], 0
        for c in self.counts:
            total += c
            cumulative.append(total)
        return HistogramSnapshot(self.bounds, tuple(cumulative), self.sum_s, total)


@dataclass
class _Camera:
    timeout_s: float
    arrivals: deque[float]
    frames: int = 0
    reconnects: int = 0
    dropped: int = 0
    lost: bool = False  # a reconnect since the last frame: down until the next one
    rates: CameraRates = field(default_factory=CameraRates)


@dataclass
class _Queue:
    size: QueueProbe
    dropped: Callable[[], int] | None
    last_dropped: int | None = None
    last_drop_t: float | None = None


def _duration(value: object) -> float | None:
    """A duration in seconds as given by the loop, or None when it is not one (NaN, negative)."""
    v = _time(value)
    return v if v is not None and v >= 0 else None


def _time(value: object) -> float | None:
    """A finite time on the clock, or None."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    try:
        v = float(value)
    except OverflowError:  # an integer beyond any float
        return None
    return v if math.isfinite(v) else None


def _count(value: object) -> int | None:
    """A count (a probe's, or frames dropped), or None when it is not an integer in [0, 2^63)."""
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value < 1 << 63:
        return None
    return value


class ServiceState:
    """Thread-safe running figures of the service (see the module docstring).

    cameras: the cameras expected (down until their first frame); others are added on their
    first call. camera_timeout_s: a camera whose last frame is older than this is down.
    """

    def __init__(
        self,
        cameras: Iterable[str] = (),
        *,
        camera_timeout_s: float = 5.0,
        latency_buckets_s: Sequence[float] = LATENCY_BUCKETS_S,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        if not (_duration(camera_timeout_s) or 0.0) > 0:
            raise ValueError(f"camera_timeout_s must be a positive number, got {camera_timeout_s}")
        bounds = tuple(float(b) for b in latency_buckets_s)
        if not bounds or any(b <= a for a, b in pairwise(bounds)):
            raise ValueError(f"latency buckets must be increasing, got {list(bounds)}")
        self._lock = threading.Lock()
        self._clock = clock
        self._started = clock()
        self._timeout_s = float(camera_timeout_s)
        self._bounds = bounds
        self._cameras: dict[str, _Camera] = {}
        self._stages: dict[str, _Histogram] = {}
        self._end_to_end = _Histogram(bounds)
        self._events: dict[str, int] = {}
        self._queues: dict[str, _Queue] = {}
        self._outputs: dict[str, OutputWatch] = {}
        self._storage: StorageProbe | None = None
        self._alarms: Callable[[], Mapping[str, object]] | None = None
        self._regions: Callable[[], Mapping[str, Mapping[str, float]]] | None = None
        self._light: Callable[[], Mapping[str, Mapping[str, object]]] | None = None
        self._frames = 0
        self._people = 0
        self._stall: str | None = None
        self._refused: set[str] = set()  # kinds of name already warned about (cap reached)
        for name in cameras:
            self.add_camera(name)

    # -- writers: the frame loop and the camera readers ----------------------------------------

    def add_camera(
        self,
        name: str,
        timeout_s: float | None = None,
        *,
        nominal_fps: float | None = None,
        source_fps: float | None = None,
    ) -> None:
        """Expect camera `name` (down until its first frame); timeout_s: its own timeout;
        nominal_fps: the frames per second the service should process of it (its rate, or
        [input] detect_fps), None: not judged; source_fps: the camera's own rate, when the
        nominal is lower (its other frames are passed over, not dropped for want of time)."""
        timeout = self._timeout_s if timeout_s is None else _duration(timeout_s)
        if not timeout:
            raise ValueError(f"camera {name!r}: timeout_s must be a positive number")
        nominal, own = _duration(nominal_fps), _duration(source_fps)
        with self._lock:
            cam = self._camera(name)
            if cam is not None:
                cam.timeout_s = timeout
                cam.rates.set_nominal(nominal, own)

    def camera_rate(
        self, name: str, nominal_fps: float | None, source_fps: float | None = None
    ) -> None:
        """Camera `name`'s nominal rate (and its own), as for add_camera, once they are known
        (a live stream's, when it connects); its timeout is left as it is."""
        nominal, own = _duration(nominal_fps), _duration(source_fps)
        with self._lock:
            cam = self._camera(name)
            if cam is not None:
                cam.rates.set_nominal(nominal, own)

    def camera_frame(self, name: str, t_arrival: float | None = None) -> None:
        """Camera `name` delivered a frame at t_arrival (None: now) on the state's clock."""
        with self._lock:
            cam = self._camera(name)
            if cam is None:
                return
            now, t = self._clock(), _time(t_arrival)
            t = now if t is None else min(t, now)  # none, not a time, or not yet: now
            if cam.arrivals and t < cam.arrivals[-1]:  # out of order: as the last one
                t = cam.arrivals[-1]
            cam.arrivals.append(t)
            cam.rates.processed.add(t)
            cam.frames += 1
            cam.lost = False

    def camera_dropped(self, name: str, n: int = 1) -> None:
        """Camera `name` dropped n frames (the loop could not keep up, or the stream lost them)."""
        with self._lock:
            cam = self._camera(name)
            if cam is not None and (k := _count(n)):
                cam.dropped += k
                cam.rates.drops.add(self._clock(), k)

    def camera_reconnect(self, name: str) -> None:
        """Camera `name` lost its stream and reopens it: down until its next frame."""
        with self._lock:
            cam = self._camera(name)
            if cam is not None:
                cam.reconnects += 1
                cam.lost = True

    def on_frame(
        self, result: FrameResult, timings: Mapping[str, float], t_arrival: float | None = None
    ) -> None:
        """One frame through the loop. result: its FrameResult (people counted from
        `people3d.ids`); timings: stage -> seconds spent on this frame; t_arrival: when its
        frames arrived, on the state's clock (end-to-end latency = now - t_arrival; None: the
        sum of the stage times). Zone events are counted by `on_events`, not here."""
        ids = result.people3d.ids if isinstance(result, FrameResult) else ()  # never raises
        stages = {str(k): d for k, v in timings.items() if (d := _duration(v)) is not None}
        arrival = _time(t_arrival)
        with self._lock:
            now = self._clock()
            self._frames += 1
            self._people = len(ids)
            for stage, seconds in stages.items():
                hist = self._stage(stage)
                if hist is not None:
                    hist.observe(seconds)
            latency = sum(stages.values()) if arrival is None else max(now - arrival, 0.0)
            self._end_to_end.observe(latency)

    def on_event(self, event: Event) -> None:
        """One zone event (its `type` counted)."""
        self.on_events([event])

    def on_events(self, events: Iterable[Event]) -> None:
        """Zone events of one frame; fits run_frames' on_events."""
        types = [str(e.type) if isinstance(e, Event) else "unknown" for e in events]
        with self._lock:
            for t in types:
                if t in self._events or self._admit("event type", t, self._events):
                    self._events[t] = self._events.get(t, 0) + 1

    def service_stall(self, reason: str | None) -> None:
        """The whole service stalled (site.health.stall: reason, e.g. since when), or None: it
        runs again."""
        with self._lock:
            self._stall = None if reason is None else str(reason)[:200]

    def register_queue(
        self, name: str, size: QueueProbe, dropped: Callable[[], int] | None = None
    ) -> None:
        """A queue to report: size() its length now, dropped() how many it has dropped so far.
        Both are called at each health or metrics read, outside the lock: they must be quick
        and must not block."""
        with self._lock:
            if name in self._queues or self._admit("queue", name, self._queues):
                self._queues[name] = _Queue(size, dropped)

    def register_output(self, name: str, health: OutputProbe) -> None:
        """An alarm output to watch: health() its (ok, waiting, reason) now (io.sinks.health),
        called at each health or metrics read, outside the lock: quick, never blocking."""
        with self._lock:
            if name in self._outputs or self._admit("output", name, self._outputs):
                self._outputs[name] = OutputWatch(health)

    def register_alarms(self, probe: Callable[[], Mapping[str, object]]) -> None:
        """probe(): the alarm rates' figures; called at each read, must be quick."""
        with self._lock:
            self._alarms = probe

    def register_regions(self, probe: Callable[[], Mapping[str, Mapping[str, float]]]) -> None:
        """probe(): detection in regions' figures by camera; called at each read, quick."""
        with self._lock:
            self._regions = probe

    def register_storage(self, probe: StorageProbe) -> None:
        """probe(): bytes used per kind of stored data; called at each read, must be quick."""
        with self._lock:
            self._storage = probe

    def register_light(self, probe: Callable[[], Mapping[str, Mapping[str, object]]]) -> None:
        """probe(): each camera's light (detection.light.LightWatch.figures); quick."""
        with self._lock:
            self._light = probe

    # -- reader: the HTTP side ---------------------------------------------------------------

    def snapshot(self) -> Snapshot:
        """Everything at one moment; the probes are called first, outside the lock."""
        with self._lock:
            queues = dict(self._queues)
            outputs = dict(self._outputs)
            storage_probe = self._storage
            alarms_probe = self._alarms
            regions_probe = self._regions
            light_probe = self._light
        problems: list[str] = []
        light = _probed(light_probe, "cameras' light", problems)
        regions = _probed(regions_probe, "detection regions", problems)
        alarms = _probed(alarms_probe, "alarm rates", problems)
        probed = {name: self._probe_queue(name, q, problems) for name, q in queues.items()}
        healths = {name: o.probe(name) for name, o in outputs.items()}
        storage = self._probe_storage(storage_probe, problems)
        with self._lock:
            now = self._clock()
            cameras = tuple(self._camera_snapshot(n, c, now) for n, c in self._cameras.items())
            stall = self._stall
            queue_snaps = tuple(self._queue_snapshot(n, *probed[n], now) for n in probed)
            output_snaps = tuple(outputs[n].snapshot(n, *healths[n], now) for n in healths)
            snap = Snapshot(
                version=__version__,
                uptime_s=max(now - self._started, 0.0),
                frames=self._frames,
                people=self._people,
                cameras=cameras,
                stages={k: h.snapshot() for k, h in self._stages.items()},
                end_to_end=self._end_to_end.snapshot(),
                events=dict(self._events),
                queues=queue_snaps,
                storage=storage,
                outputs=output_snaps,
                alarms=alarms,
                regions=regions,
                light=light,
            )
        if stall is not None:
            problems.append(f"service {stall}")
        problems += [f"camera {c.name} down" for c in cameras if not c.up]
        problems += [f"camera {c.name}: {c.slow}" for c in cameras if c.up and c.slow]
        problems += [f"queue {q.name} dropping" for q in queue_snaps if q.dropping]
        problems += [p for o in output_snaps if (p := o.problem)]
        return replace(snap, problems=tuple(problems))

    # -- inside ---------------------------------------------------------------------------------

    def _admit(self, kind: str, name: str, table: Mapping[str, object]) -> bool:
        """Whether one more name fits in table (the lock held); warns once per kind if not."""
        if len(table) < MAX_NAMES:
            return True
        if kind not in self._refused:
            self._refused.add(kind)
            logger.warning(
                "more than %d %s names; %r and later ones not reported", MAX_NAMES, kind, name
            )
        return False

    def _camera(self, name: str) -> _Camera | None:
        cam = self._cameras.get(name)
        if cam is None and self._admit("camera", name, self._cameras):
            cam = self._cameras[name] = _Camera(self._timeout_s, deque(maxlen=FPS_WINDOW))
        return cam

    def _stage(self, name: str) -> _Histogram | None:
        hist = self._stages.get(name)
        if hist is None and self._admit("stage", name, self._stages):
            hist = self._stages[name] = _Histogram(self._bounds)
        return hist

    @staticmethod
    def _camera_snapshot(name: str, cam: _Camera, now: float) -> CameraSnapshot:
        age = max(now - cam.arrivals[-1], 0.0) if cam.arrivals else None
        up = age is not None and age <= cam.timeout_s and not cam.lost
        span = cam.arrivals[-1] - cam.arrivals[0] if len(cam.arrivals) > 1 else 0.0
        fps = (len(cam.arrivals) - 1) / span if up and span > 0 else 0.0
        processed, share, slow = cam.rates.judge(now)
        return CameraSnapshot(
            name,
            fps,
            age,
            up,
            cam.frames,
            cam.reconnects,
            cam.dropped,
            cam.timeout_s,
            cam.rates.nominal_fps,
            processed,
            share,
            slow,
        )

    def _queue_snapshot(
        self, name: str, size: int | None, dropped: int | None, now: float
    ) -> QueueSnapshot:
        q = self._queues[name]
        if dropped is not None:
            if q.last_dropped is not None and dropped > q.last_dropped:
                q.last_drop_t = now
            q.last_dropped = dropped
        dropping = q.last_drop_t is not None and now - q.last_drop_t <= DROP_WINDOW_S
        return QueueSnapshot(name, size, dropped, dropping)

    @staticmethod
    def _probe_queue(name: str, q: _Queue, problems: list[str]) -> tuple[int | None, int | None]:
        values = []
        for what, probe in (("size", q.size), ("dropped", q.dropped)):
            if probe is None:
                values.append(None)
                continue
            try:
                value = _count(probe())
            except Exception:  # a probe's failure is reported, never the reader's
                logger.exception("queue %s: its %s probe failed", name, what)
                value = None
            if value is None:
                problems.append(f"queue {name}: {what} unknown")
            values.append(value)
        return values[0], values[1]

    @staticmethod
    def _probe_storage(probe: StorageProbe | None, problems: list[str]) -> dict[str, int]:
        if probe is None:
            return {}
        try:
            raw = dict(probe())
        except Exception:
            logger.exception("the storage probe failed")
            problems.append("storage: unknown")
            return {}
        storage = {str(k): v for k, v in raw.items() if _count(v) is not None}
        if len(storage) != len(raw):
            problems.append("storage: some sizes unknown")
        return dict(list(storage.items())[:MAX_NAMES])


def _probed(probe: Callable[[], Mapping] | None, what: str, problems: list[str]) -> dict:
    """What `probe` gives, as a dict ({} without one); a probe failing never stops the
    health answer: its failure is one of `problems`."""
    if probe is None:
        return {}
    try:
        return dict(probe())
    except Exception as e:
        problems.append(f"{what}: {e}")
        return {}
