"""Cameras with detection on its own thread: a frame-loop source whose steps carry their people.

Three stages run at once: each live camera reads on its own thread (io.stream), detection runs
on this source's thread (reading the cameras' newest frames when it is ready for the next
step), and the 3D stage and the sinks on the frame loop's thread. Between detection and the
loop is a hand-over of `queue_size` steps: with live cameras the newest step wins and a step
the loop did not take in time is dropped (counted in `dropped`); with recorded cameras
detection waits for the loop instead (every frame of a file is kept). So the loop always gets
the newest detected step, and detection never waits for the 3D stage.

Latency: a step's oldest frame arrival (live: when it was grabbed; recorded: when it was read)
to the end of the loop's work on it (when the loop asks for the next step), kept for the last
LATENCY_KEPT steps.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field

import numpy as np

from stereopose.io.summary import RunSummary
from stereopose.pipeline.loop import SourceStep
from stereopose.pipeline.sources import Cameras
from stereopose.types import People2D, People3D

logger = logging.getLogger(__name__)

LATENCY_KEPT = 4096
JOIN_S = 10.0  # the longest close() waits for one detection step to end


class Handover:
    """A bounded hand-over between two threads. put(): with `drop`, an unread item is
    replaced (newest wins, `dropped` counts it); without, put waits until there is room;
    `force` (the end, an error) puts at once, behind the items waiting (one over the bound).
    get(timeout) gives the oldest item, or None after timeout. close() wakes both sides."""

    def __init__(self, size: int = 1, drop: bool = True) -> None:
        if size < 1:
            raise ValueError(f"a hand-over holds at least 1 item, got {size}")
        self.size, self.drop = size, drop
        self.items: deque = deque()
        self.dropped = 0
        self.closed = False
        self._cond = threading.Condition()

    def put(self, item: object, *, force: bool = False) -> bool:
        """Whether the item was put (False: closed)."""
        with self._cond:
            while not (self.drop or force) and len(self.items) >= self.size and not self.closed:
                self._cond.wait(0.1)
            if self.closed:
                return False
            # a forced item (the end, an error) goes behind what is waiting, never in its place
            while not force and len(self.items) >= self.size:
                self.items.popleft()
                self.dropped += 1
            self.items.append(item)
            self._cond.notify_all()
            return True

    def get(self, timeout: float) -> object | None:
        with self._cond:
            if not self.items and not self.closed:
                self._cond.wait(timeout)
            if not self.items:
                return None
            item = self.items.popleft()
            self._cond.notify_all()
            return item

    def close(self) -> None:
        with self._cond:
            self.closed = True
            self._cond.notify_all()

    def __len__(self) -> int:
        return len(self.items)


@dataclass
class PipelineStats:
    """What the pipeline did: steps detected and handed over, dropped, time in detection."""

    detected: int = 0
    delivered: int = 0
    dropped: int = 0
    detect_s: float = 0.0
    wait_s: float = 0.0  # detection's thread waiting for the cameras' frames
    latency_s: deque = field(default_factory=lambda: deque(maxlen=LATENCY_KEPT))

    def figures(self) -> dict[str, float | None]:
        """The summary's `pipeline`: steps, drops, detection seconds, latency p50/p95 (s;
        None before any step)."""
        kept = bool(self.latency_s)
        return {
            "detected": self.detected,
            "delivered": self.delivered,
            "dropped": self.dropped,
            "detect_s": self.detect_s,
            "wait_s": self.wait_s,
            "latency_p50_s": self.latency(0.5) if kept else None,
            "latency_p95_s": self.latency(0.95) if kept else None,
        }

    def latency(self, q: float) -> float:
        """The q-quantile (0..1) of the kept latencies, seconds; NaN when none."""
        return float(np.quantile(list(self.latency_s), q)) if self.latency_s else float("nan")


_END = object()


class PipelinedCameras:
    """`Cameras` (pipeline.sources) with detection on its own thread (see the module).

    drop: newest step wins at the hand-over (default: for live cameras). close() (also done by
    `finish`) stops detection's thread, waiting at most JOIN_S, and ends the cameras' waits.
    """

    def __init__(self, cameras: Cameras, *, queue_size: int = 1, drop: bool | None = None) -> None:
        self.inner = cameras
        self.cameras, self.stages = cameras.cameras, cameras.stages
        self.fps, self.live = cameras.fps, cameras.live
        self.handover = Handover(queue_size, cameras.live if drop is None else drop)
        self.stats = PipelineStats()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    @property
    def total(self) -> int | None:
        return self.inner.total

    def __iter__(self) -> Iterator[SourceStep]:
        if self._thread is not None:
            raise RuntimeError("a pipelined source is iterated once")
        self._thread = threading.Thread(target=self._detect_steps, name="detection", daemon=True)
        self._thread.start()
        arrived: float | None = None
        try:
            while True:
                item = self.handover.get(0.1)
                if arrived is not None:  # the loop asked again: the last step is done
                    self.stats.latency_s.append(time.monotonic() - arrived)
                    arrived = None
                if item is None:
                    if self.handover.closed:
                        return
                    continue
                if item is _END:
                    return
                if isinstance(item, BaseException):
                    raise item
                assert isinstance(item, tuple)  # (step, its arrival)
                step, arrived = item
                self.stats.delivered += 1
                yield step
        finally:
            self.close()

    def _detect_steps(self) -> None:
        it = iter(self.inner)
        try:
            while not self._stop.is_set():
                t0 = time.perf_counter()
                step = next(it, None)
                t1 = time.perf_counter()
                self.stats.wait_s += t1 - t0
                if step is None or self._stop.is_set():
                    break
                arrived = self.inner.arrival(step)
                people2d = self.inner.detect(step)
                self.stats.detect_s += time.perf_counter() - t1
                self.stats.detected += 1
                done = SourceStep(step.frame, step.t, people2d, step.images)
                if not self.handover.put((done, arrived)):
                    break
                self.stats.dropped = self.handover.dropped
            self.handover.put(_END, force=True)
        except BaseException as e:  # raised on the loop's thread
            self.handover.put(e, force=True)

    def detect(self, step: SourceStep) -> Mapping[str, People2D]:
        raise TypeError("a pipelined source's steps carry their people")

    def tracked(self, people: People3D) -> None:
        """The loop's people of its last step, for the regions of the steps detected next."""
        self.inner.tracked(people)

    def close(self) -> None:
        """Stop detection's thread (it ends after its current step) and wait for it."""
        self._stop.set()
        self.inner.cams.end()
        self.handover.close()
        thread = self._thread
        if thread is not None and thread is not threading.current_thread():
            thread.join(JOIN_S)
            if thread.is_alive():
                logger.warning("detection did not end within %.0f s of closing", JOIN_S)
        self.stats.dropped = self.handover.dropped

    def finish(self, summary: RunSummary) -> None:
        """The inner source's figures, and the time detection took (on its own thread: the
        loop's first stage is then the time it waited for a detected step)."""
        self.close()
        self.inner.finish(summary)
        summary.seconds["detect"] = summary.seconds.get("detect", 0.0) + self.stats.detect_s
        summary.pipeline = self.stats.figures()
