"""Parts of `stereopose serve` around the frame loop: its source, the sinks that feed
the health state and status.json, and the stop signals.

- `ServeSource` takes the steps of any frame-loop source on a thread of its own, and gives
  the loop an empty step (no images, nobody) whenever the source has given nothing for
  `heartbeat_s`, stamped with `clock()` (the service's time now) when given: time goes on for
  the camera watch and the stall watch (site.steps), and the events of a blind
  camera get out although no frame comes. Steps that carry their people
  (pipelined detection) are told to `on_detect` as those found by `detect` are.
- `StateSink` feeds the ServiceState (cameras' frames, stage times, people, events, the
  readers' drops and reconnects); `StatusSink` writes status.json (the health snapshot) every
  `interval_s`, atomically, and once more at close.
- `output_health` is the health probe of an alarm output behind its Guarded wrapper (down once
  the wrapper has stopped it).
- `stop_signals` makes SIGTERM act as SIGINT does (the frame loop's Ctrl-C: stop after the
  step in progress, at once while waiting), and `quiet_signals` ignores both while the outputs
  close, so a second signal cannot cut a close short.
"""

from __future__ import annotations

import contextlib
import json
import logging
import math
import os
import queue
import signal
import threading
import time
from collections.abc import Callable, Iterator, Mapping
from pathlib import Path
from types import FrameType
from typing import TYPE_CHECKING

from stereopose.io.sinks.base import ClosesOnce, FrameResult, Guarded
from stereopose.io.sinks.health import ReportsHealth
from stereopose.io.source import SourceStats
from stereopose.io.summary import RunSummary
from stereopose.pipeline.loop import Source, SourceStep
from stereopose.types import People2D, People3D

if TYPE_CHECKING:
    from stereopose.site.health.state import ServiceState

logger = logging.getLogger(__name__)

_END = object()


class ServeSource:
    """A frame-loop source for the service (see the module). Steps are renumbered from 0 and
    their times made strictly increasing; `heartbeats` counts the empty steps given."""

    def __init__(
        self,
        inner: Source,
        *,
        stop: threading.Event,
        heartbeat_s: float = 0.5,
        on_step: Callable[[SourceStep], None] | None = None,
        on_detect: Callable[[Mapping[str, People2D]], None] | None = None,
        clock: Callable[[], float] | None = None,
    ) -> None:
        self.inner, self.stop, self.clock = inner, stop, clock
        self.cameras, self.stages = inner.cameras, inner.stages
        self.fps, self.live = inner.fps, inner.live
        self.heartbeat_s = heartbeat_s
        self.on_step, self.on_detect = on_step, on_detect
        self.heartbeats = 0
        self._want = threading.Event()
        self._got: queue.Queue = queue.Queue(1)
        self._thread: threading.Thread | None = None

    @property
    def total(self) -> int | None:
        return None

    def _produce(self) -> None:
        it = iter(self.inner)
        while not self.stop.is_set():
            if not self._want.wait(0.2):
                continue
            self._want.clear()
            try:
                item = next(it, _END)
            except BaseException as e:  # the loop's thread raises it
                item = e
            self._got.put(item)
            if item is _END or isinstance(item, BaseException):
                return

    def __iter__(self) -> Iterator[SourceStep]:
        self._thread = threading.Thread(target=self._produce, name="serve-source", daemon=True)
        self._thread.start()
        frame, last_t, last_mono = 0, -math.inf, time.monotonic()
        pending = False
        while not self.stop.is_set():
            if not pending:
                self._want.set()
                pending = True
            item = self._wait()
            now = time.monotonic()
            if item is None:  # nothing for heartbeat_s: an empty step, time going on
                if self.stop.is_set():
                    return
                if self.clock is not None:
                    t = max(float(self.clock()), last_t + 1e-4)
                else:
                    t = last_t + (now - last_mono) if math.isfinite(last_t) else 0.0
                self.heartbeats += 1
                step = SourceStep(frame, t, {}, None)
            else:
                pending = False
                if item is _END:
                    return
                if isinstance(item, BaseException):
                    raise item
                assert isinstance(item, SourceStep)  # the inner source's
                t = max(float(item.t), last_t + 1e-4) if math.isfinite(last_t) else float(item.t)
                step = SourceStep(frame, t, item.people2d, item.images)
            frame, last_t, last_mono = frame + 1, step.t, now
            if self.on_step is not None:
                self.on_step(step)
            if item is not None and step.people2d is not None and self.on_detect is not None:
                self.on_detect(step.people2d)  # a pipelined source's step carries its people
            yield step

    def _wait(self) -> object | None:
        deadline = time.monotonic() + self.heartbeat_s
        while True:
            left = deadline - time.monotonic()
            if left <= 0 or self.stop.is_set():
                return None
            try:
                return self._got.get(timeout=min(left, 0.1))
            except queue.Empty:
                continue

    def detect(self, step: SourceStep) -> Mapping[str, People2D]:
        people2d = self.inner.detect(step)
        if self.on_detect is not None:
            self.on_detect(people2d)
        return people2d

    def tracked(self, people: People3D) -> None:
        """The loop's people of its last step, to a source that detects in regions."""
        self.inner.tracked(people)

    def finish(self, summary: RunSummary) -> None:
        self.inner.finish(summary)


class StateSink(ClosesOnce):
    """Feeds `state` (site.health.state.ServiceState) and the run's `summary` (its running
    aggregates) from each frame: which cameras delivered, the seconds each stage took since the
    last frame (from summary.seconds), people and events. arrival(t): a step
    time's monotonic time (None: not known, the latency is the sum of the stages); stats(): the
    camera readers' figures (io.source.SourceStats by camera), read every `stats_s`;
    elsewhere(): seconds so far of the stages timed off the loop's thread (a pipelined
    detection), by stage, added to the summary's; rates(): per camera (nominal fps, its own
    fps), told to the state when they change (read with the stats)."""

    stage = "state"

    def __init__(
        self,
        state: ServiceState,
        summary: RunSummary,
        *,
        arrival: Callable[[float], float | None] = lambda t: None,
        stats: Callable[[], Mapping[str, SourceStats]] | None = None,
        stats_s: float = 1.0,
        elsewhere: Callable[[], Mapping[str, float]] | None = None,
        rates: Callable[[], Mapping[str, tuple[float | None, float | None]]] | None = None,
    ) -> None:
        self.state, self.summary, self.seconds = state, summary, summary.seconds
        self.elsewhere, self.rates = elsewhere, rates
        self._rates: dict[str, tuple[float | None, float | None]] = {}
        self.arrival, self.stats, self.stats_s = arrival, stats, stats_s
        self._last = dict(self.seconds)
        self._seen: dict[str, tuple[int, int]] = {}  # camera -> (dropped, reconnects) so far
        self._stats_at = -math.inf

    def write(self, frame: FrameResult) -> None:
        for name, image in (frame.images or {}).items():
            if image is not None:
                self.state.camera_frame(name)
        now = dict(self.seconds)
        if self.elsewhere is not None:
            for stage, seconds in self.elsewhere().items():
                now[stage] = now.get(stage, 0.0) + seconds
        timings = {k: v - self._last.get(k, 0.0) for k, v in now.items()}
        self._last = now
        self.state.on_frame(frame, timings, self.arrival(frame.t))
        self.summary.add(frame.people3d, frame.events)
        if frame.events:
            self.state.on_events(frame.events)
        if self.stats is not None and time.monotonic() - self._stats_at >= self.stats_s:
            self._stats_at = time.monotonic()
            self._readers()
            self._nominal()

    def _nominal(self) -> None:
        for name, (nominal, own) in (self.rates() if self.rates else {}).items():
            if self._rates.get(name) != (nominal, own):
                self._rates[name] = (nominal, own)
                self.state.camera_rate(name, nominal, own)

    def _readers(self) -> None:
        stats = self.stats
        assert stats is not None  # read only where there are figures
        for name, st in stats().items():
            dropped, reconnects = st.dropped, st.reconnects
            was_dropped, was_reconnects = self._seen.get(name, (0, 0))
            if dropped > was_dropped:
                self.state.camera_dropped(name, dropped - was_dropped)
            if reconnects > was_reconnects:
                self.state.camera_reconnect(name)
            self._seen[name] = (dropped, reconnects)

    def _close(self) -> list[Path]:
        return []


class StatusSink(ClosesOnce):
    """status.json: `snapshot()` (a JSON-able dict) written every interval_s of wall time and
    at close, through a temporary file renamed over it, so a reader never sees half of one.
    A failed write is logged once per spell and tried again at the next interval."""

    stage = "write"

    def __init__(self, path: Path, snapshot: Callable[[], dict], interval_s: float) -> None:
        self.path, self.snapshot, self.interval_s = Path(path), snapshot, interval_s
        self._next = -math.inf
        self._failing = False
        self.writes = self.failures = 0

    def write(self, frame: FrameResult) -> None:
        if time.monotonic() >= self._next:
            self.write_now()

    def write_now(self) -> bool:
        """Write the snapshot now; whether it was written."""
        self._next = time.monotonic() + self.interval_s
        tmp = self.path.with_name(f".{self.path.name}.{os.getpid()}.tmp")
        try:
            text = json.dumps(self.snapshot(), indent=1, default=str)
            with open(tmp, "w", encoding="utf-8") as f:
                f.write(text + "\n")
            os.replace(tmp, self.path)
        except OSError as e:
            self.failures += 1
            with contextlib.suppress(OSError):
                tmp.unlink()
            if not self._failing:
                logger.error(
                    "%s: cannot write the status (%s); tried again every %g s",
                    self.path,
                    e.strerror or e,
                    self.interval_s,
                )
            self._failing = True
            return False
        if self._failing:
            logger.warning("%s: status written again", self.path)
        self._failing = False
        self.writes += 1
        return True

    def _close(self) -> list[Path]:
        return [self.path] if self.write_now() else []


def output_health(out: ReportsHealth, sink: Guarded) -> Callable[[], tuple[bool, int, str | None]]:
    """The probe of an alarm output (io.sinks.health) for ServiceState.register_output:
    its own health(), and down once its Guarded wrapper `sink` has stopped it after a
    failure."""

    def probe() -> tuple[bool, int, str | None]:
        ok, waiting, reason = out.health()
        if sink.failed:  # the failure itself (it may name a file) is logged
            return False, waiting, "stopped after a failure (see the log)"
        return ok, waiting, reason

    return probe


@contextlib.contextmanager
def stop_signals() -> Iterator[None]:
    """SIGTERM handled as SIGINT is at that moment (main thread only); on leaving, SIGINT and
    SIGTERM as they were on entering."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def as_sigint(signum: int, frame: FrameType | None) -> None:
        handler = signal.getsignal(signal.SIGINT)
        if callable(handler):
            handler(signal.SIGINT, frame)
        else:
            raise KeyboardInterrupt

    previous = signal.signal(signal.SIGTERM, as_sigint)
    previous_int = signal.getsignal(signal.SIGINT)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)
        # the frame loop's Ctrl-C handler and the closing's quiet one are undone in the order
        # the closing needs, not the order they were made: SIGINT is put back as it was here
        if previous_int is not None:
            signal.signal(signal.SIGINT, previous_int)


@contextlib.contextmanager
def reload_signal(reload: Callable[[], object] | None) -> Iterator[None]:
    """SIGHUP calls `reload` on a thread of its own (the site file read again: systemctl
    reload); on leaving, SIGHUP as it was (main thread only; nothing without `reload`)."""
    if reload is None or threading.current_thread() is not threading.main_thread():
        yield
        return

    def hup(signum: int, frame: object) -> None:
        threading.Thread(target=reload, name="site-reload", daemon=True).start()

    previous = signal.signal(signal.SIGHUP, hup)
    try:
        yield
    finally:
        signal.signal(signal.SIGHUP, previous)


@contextlib.contextmanager
def quiet_signals() -> Iterator[None]:
    """SIGINT and SIGTERM logged and otherwise ignored (main thread only): the outputs are
    closing, each within its own bound."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def note(signum: int, frame: object) -> None:
        logger.warning("already stopping: closing the outputs")

    previous = {s: signal.signal(s, note) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
