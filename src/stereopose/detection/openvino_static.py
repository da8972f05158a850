"""OpenVINO models compiled for the input shapes a detector meets most, beside its dynamic one.

A model compiled with dynamic input shapes (any batch, any size: what regions and whole frames
of any camera need) works out its shapes and memory at every call. A model compiled for one
shape does that once, and its kernels are chosen for that shape: on the 2-core AMD EPYC, bf16,
four whole demo frames took 30.7 ms against 33.1, one frame 9.3 against 10.4, one 320-pixel
region 4.3 against 5.2 (1.08x to 1.19x; benchmarks/results/static_shapes.md): the fixed part
of a call shrinks most, which is what regions pay for. Compiling one takes about 200 ms and
holds about 60 MB more.

`StaticShapes` counts the calls of each (way, batch, height, width) and compiles a model for
one once it has been called AFTER times (a shape common enough to repay its compile). At most
MOST are kept per detector. A new common shape takes the place of a model only when that model
has gone unused for IDLE calls (cameras added, removed or changed on a service that runs for
weeks): a model in use is never swapped out and in again, so no busy shape pays its compile
twice. The rest run on the dynamic model. The same outputs either way, to the precision's own
rounding.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import openvino as ov

logger = logging.getLogger(__name__)

# calls of one shape before a model is compiled for it: a shape this common repays its compile
# (about 150 ms) within about as many calls again, at the 1-1.6 ms a call saves; a short run
# (`run` on 100 frames) compiles nothing; and the call prices' measure (detection.call_costs,
# at most 12 calls of one shape) prices the dynamic model alone
AFTER = 128
MOST = 4  # models compiled for one shape, at most, per detector
IDLE = 4096  # calls without one of them before another shape may take its place
COUNTED = 64  # shapes counted at once, at most (the counts start again beyond)

Key = tuple[str, int, int, int]  # way ("one": one request; "split": over the streams), n, h, w


class StaticShapes:
    """The requests of models compiled for single shapes: `requests(key)` gives those of the
    model for `key` (counting the call, and compiling it on its AFTER-th), or None while the
    dynamic model runs it. compile(key) -> (the compiled model's requests), the detector's
    own way of compiling (the same precision, threads and streams as its dynamic model)."""

    def __init__(self, compile: Callable[[Key], list[ov.InferRequest]]) -> None:
        self._compile = compile
        self._lock = threading.Lock()
        self._counts: dict[Key, int] = {}
        self._made: dict[Key, list[ov.InferRequest]] = {}
        self._used: dict[Key, int] = {}  # the call each model was last used at
        self._clock = 0  # calls counted
        self.failed = False  # a compile failed: no more are tried
        self.calls = 0  # calls run on a model of their own shape
        self.compile_ms = 0.0  # spent compiling, in all
        self.released = 0  # models let go for a new shape, having gone unused

    def requests(self, key: Key) -> list[ov.InferRequest] | None:
        with self._lock:
            self._clock += 1
            made = self._made.get(key)
            if made is not None:
                self.calls += 1
                self._used[key] = self._clock
                return made
            if self.failed:
                return None
            n = self._counts.get(key, 0) + 1
            if n < AFTER:
                if key not in self._counts and len(self._counts) >= COUNTED:
                    self._counts.clear()
                self._counts[key] = n
                return None
            if len(self._made) >= MOST and not self._release():
                self._counts[key] = n  # counted on: it may take an idle model's place later
                return None
            self._counts.pop(key, None)
            t0 = time.perf_counter()
            try:
                made = self._compile(key)
            except Exception as e:  # a model that cannot take a fixed shape: dynamic only
                self.failed = True
                logger.warning("openvino: no model compiled for %s: %s", _said(key), e)
                return None
            ms = 1000 * (time.perf_counter() - t0)
            self.compile_ms += ms
            self._made[key] = made
            self._used[key] = self._clock
            self.calls += 1
        logger.debug("openvino: a model compiled for %s in %.0f ms", _said(key), ms)
        return made

    def _release(self) -> bool:
        """Let go of the model unused longest if it has gone unused for IDLE calls (under
        the lock); whether one was."""
        idle = min(self._made, key=lambda k: self._used[k])
        if self._clock - self._used[idle] < IDLE:
            return False
        del self._made[idle], self._used[idle]
        self.released += 1
        logger.debug("openvino: the model for %s let go (unused)", _said(idle))
        return True

    @property
    def shapes(self) -> list[Key]:
        """The shapes that have a model of their own, in the order they were made."""
        with self._lock:
            return list(self._made)


def _said(key: Key) -> str:
    way, n, h, w = key
    return f"batches of {n} {h}x{w}" + (" over the streams" if way == "split" else "")
