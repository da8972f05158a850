"""What a model call costs on this machine, and the cheapest calls for a step of regions.

A detector's call costs a fixed part whatever it holds (Intel's AMX pays a large one; an AMD
with AVX-512 hides it) and a part that grows with its batch, not always in a straight line
(OpenVINO splits a batch over two inference streams on two cores: three images may cost more
than two calls of two and one). So the price of a call is measured, not counted in pixels: for
each model input shape, the fastest of a few timed calls of batches of 1, 2, ... images (a busy
moment only slows a call down), up to MEASURED_MAX, beyond that the last two measures' line.
A batch is then made in the calls that cost least (`split`: one call where a call's fixed part
is large, as on Intel's AMX; 2 + 1 where three in one cost more), and each camera's regions and
whole frames go into as few and as cheap calls as their detail allows (`cheapest`).

Prices are measured the first time a shape is needed (a few hundred milliseconds) and kept per
machine in ``<cache>/models/call_costs.json`` (the CPU, the runtime, the model, its precision
and threads). Every real call afterwards moves one factor common to all prices toward what it
took against its price (`observe`): the prices follow a machine busier than when they were
measured, and their ratios, which alone choose the calls, stay as measured (a call taken
more often than another under load is never priced up alone).
"""

from __future__ import annotations

import json
import logging
import os
import platform
import threading
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from stereopose.detection.base import PoseDetector

logger = logging.getLogger(__name__)

MEASURED_MAX = 8  # batches measured up to this many images; larger ones extrapolated
REPEAT = 3  # timed calls per batch size (after one to warm the shape up)
COST_FILE = "call_costs.json"
KEPT = 64  # entries kept in the file, the newest
FOLLOW = 0.2  # how far a real call moves the prices' common factor toward what it took
LOAD_RANGE = (0.25, 20.0)  # the common factor's bounds
# whole frames taken over regions, or a batch split into more calls, only where that saves
# this share of the step's (or the batch's) time
SAVING = 0.05
FORMAT = "raw"  # the prices kept: each batch as measured (tables of other formats measured anew)

Shape = tuple[int, int]  # a model input (h, w)


def _cpu() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text(encoding="utf-8").splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def detector_key(detector: PoseDetector) -> str:
    """What a price depends on besides the input: this CPU and cores, the runtime and model,
    its precision and threads."""
    own = dict(vars(detector)) if hasattr(detector, "__dict__") else {}
    parts = [_cpu(), str(os.cpu_count()), type(detector).__name__]
    parts.append(Path(str(own.get("model", ""))).name)
    parts += [str(own.get(k, "")) for k in ("precision", "runs_in", "device", "threads")]
    parts += [
        ",".join(map(str, own.get("providers") or [])),
        os.environ.get("STEREOPOSE_THREADS", ""),
        FORMAT,
    ]
    return "|".join(parts)


class CallCosts:
    """The measured price (ms) of a detector's call by input shape and batch size.

    `price(shape, n)`, of the cheapest calls for n images; `split(shape, n)`, those calls'
    sizes; `ensure(needs)` measures the shapes not priced yet (needs: shape ->
    the largest batch wanted); `observe(shape, n, ms)` after a real call; `table()` the
    prices for a report. Thread-safe; `store` None keeps nothing on disk."""

    def __init__(self, detector: PoseDetector, store: Path | None = None) -> None:
        self.detector = detector
        self.store = store
        self.key = detector_key(detector)
        self._lock = threading.Lock()
        self._ms: dict[Shape, list[float]] = {}  # shape -> price of batches 1..len
        # shape -> for 0, 1, 2, ... images: (ms of their cheapest calls, the first call's size)
        self._best: dict[Shape, list[tuple[float, int]]] = {}
        self.load = 1.0  # what real calls take against their measured price, followed
        self._load()

    @classmethod
    def of(cls, detector: PoseDetector) -> CallCosts:
        """The prices of `detector`, kept in the cache's models folder."""
        from stereopose.detection.models import models_dir

        return cls(detector, models_dir() / COST_FILE)

    def _entry(self, shape: Shape) -> str:
        return f"{self.key}|{shape[0]}x{shape[1]}"

    def _load(self) -> None:
        if self.store is None:
            return
        try:
            known = json.loads(self.store.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            return
        if not isinstance(known, dict):
            return
        prefix = f"{self.key}|"
        for k, v in known.items():
            if not (isinstance(k, str) and k.startswith(prefix)):
                continue
            try:
                h, w = (int(x) for x in k[len(prefix) :].split("x"))
                ms = [float(x) for x in v]
            except (ValueError, TypeError):
                continue
            if ms and all(np.isfinite(ms)) and min(ms) > 0:
                self._ms[(h, w)] = ms

    def _save(self, shape: Shape) -> None:
        if self.store is None:
            return
        try:
            known = json.loads(self.store.read_text(encoding="utf-8"))
            known = known if isinstance(known, dict) else {}
        except (OSError, ValueError):
            known = {}
        known.pop(self._entry(shape), None)
        known[self._entry(shape)] = [round(x, 3) for x in self._ms[shape]]
        tmp = self.store.with_name(f".{self.store.name}.{os.getpid()}")
        try:
            self.store.parent.mkdir(parents=True, exist_ok=True)
            tmp.write_text(json.dumps(dict(list(known.items())[-KEPT:]), indent=1) + "\n")
            os.replace(tmp, self.store)
        except OSError as e:  # a read-only cache: measured again next time
            logger.warning("call costs: cannot keep them in %s: %s", self.store, e)

    def priced(self, shape: Shape) -> bool:
        return (int(shape[0]), int(shape[1])) in self._ms

    def set(self, shape: Shape, ms: Sequence[float]) -> None:
        """Prices known from elsewhere (another run's table): ms for batches 1, 2, ..."""
        ms = [float(x) for x in ms]
        if not ms or not all(np.isfinite(ms)) or min(ms) <= 0:
            raise ValueError(f"prices must be positive milliseconds, got {ms!r}")
        with self._lock:
            self._ms[(int(shape[0]), int(shape[1]))] = ms
            self._best.pop((int(shape[0]), int(shape[1])), None)

    def ensure(self, needs: Mapping[Shape, int]) -> None:
        """Measure the batches of each shape not priced yet (up to its largest wanted batch,
        at most MEASURED_MAX; at least 2, so that a line can be drawn)."""
        for shape, most in needs.items():
            shape = (int(shape[0]), int(shape[1]))
            if shape in self._ms:
                continue
            upto = max(2, min(int(most), MEASURED_MAX))
            t0 = time.perf_counter()
            ms = self._measure(shape, upto)
            with self._lock:
                self._ms[shape] = ms
                self._best.pop(shape, None)
            self._save(shape)
            logger.info(
                "call costs: %dx%d input, batches 1-%d: %s ms (measured in %.1f s)",
                shape[0],
                shape[1],
                upto,
                " / ".join(f"{x:.1f}" for x in ms),
                time.perf_counter() - t0,
            )

    def _measure(self, shape: Shape, upto: int) -> list[float]:
        h, w = shape
        rng = np.random.default_rng(0)
        images = [rng.integers(0, 256, (h, w, 3), dtype=np.uint8) for _ in range(upto)]
        imgsz = max(h, w)  # the image is the input: letterboxed as it is
        square = h == w
        out = []
        for n in range(1, upto + 1):
            batch = images[:n]
            self.detector.detect(batch, imgsz=imgsz if square else None)  # warm the shape
            runs = []
            for _ in range(REPEAT):
                t0 = time.perf_counter()
                self.detector.detect(batch, imgsz=imgsz if square else None)
                runs.append(1000 * (time.perf_counter() - t0))
            out.append(min(runs))
        return [round(float(x), 3) for x in out]

    def _call_ms(self, ms: list[float], n: int) -> float:
        """ms for one call of n >= 1 images at the measured prices: beyond them, the last two
        measures' line, or the measured batches' mean step where that is steeper (a last
        measure below the one before it says nothing of larger batches)."""
        if n <= len(ms):
            return ms[n - 1]
        if len(ms) < 2:
            return ms[-1] * n
        slope = max(ms[-1] - ms[-2], (ms[-1] - ms[0]) / (len(ms) - 1), 0.0)
        return ms[-1] + slope * (n - len(ms))

    def _cheapest_calls(self, shape: Shape, n: int) -> list[tuple[float, int]] | None:
        """For 0..n images of `shape`: the ms of their cheapest calls and the first call's size
        (None: unpriced). Made once per shape and grown as larger batches are asked for."""
        with self._lock:
            ms = self._ms.get(shape)
            if not ms:
                return None
            best = self._best.setdefault(shape, [(0.0, 0)])
            for m in range(len(best), n + 1):
                one = self._call_ms(ms, m)
                split = min(
                    ((self._call_ms(ms, k) + best[m - k][0], k) for k in range(1, m)),
                    default=(one, m),
                )
                # more calls only where they save SAVING (a tie: the fewer calls)
                best.append(split if split[0] < one * (1 - SAVING) else (one, m))
            return best

    def price(self, shape: Shape, n: int) -> float:
        """ms for n images of `shape` in their cheapest calls (0 for none); unpriced: inf."""
        if n <= 0:
            return 0.0
        best = self._cheapest_calls((int(shape[0]), int(shape[1])), n)
        return float("inf") if best is None else self.load * best[n][0]

    def split(self, shape: Shape, n: int) -> list[int]:
        """The sizes of the cheapest calls for n images of `shape`, largest first ([n]: one
        call, as for an unpriced shape)."""
        best = self._cheapest_calls((int(shape[0]), int(shape[1])), n) if n > 0 else None
        if best is None:
            return [n] if n > 0 else []
        sizes = []
        while n > 0:
            sizes.append(best[n][1])
            n -= best[n][1]
        return sorted(sizes, reverse=True)

    def observe(self, shape: Shape, n: int, ms: float) -> None:
        """A real call of n images of `shape` took `ms`: the prices' common factor moves toward
        what it took against its measured price."""
        key = (int(shape[0]), int(shape[1]))
        with self._lock:
            known = self._ms.get(key)
            if not known or not 1 <= n <= len(known) or not np.isfinite(ms) or ms <= 0:
                return
            load = self.load + FOLLOW * (ms / known[n - 1] - self.load)
            self.load = min(max(load, LOAD_RANGE[0]), LOAD_RANGE[1])

    def table(self) -> dict[str, list[float]]:
        """The prices by input shape "HxW": ms for batches 1, 2, ..., as measured."""
        with self._lock:
            return {f"{h}x{w}": [round(x, 2) for x in ms] for (h, w), ms in self._ms.items()}


def cheapest(
    costs: CallCosts,
    whole: Sequence[Shape],
    crop: Shape,
    cameras: Sequence[tuple[str, Shape, int]],
) -> set[str]:
    """Which cameras of a step to detect whole rather than in their regions, for the least
    time: `whole`, the input shapes of the cameras detected whole anyway; `crop`, a region's
    input; `cameras`, those that may go either way: (name, its whole frame's input shape, its
    regions). Whole frames are taken only where they save at least SAVING of the step: a tie
    keeps the regions' detail."""
    if not cameras:
        return set()
    # the cameras with the most regions first: each saves the most crops when taken whole
    order = sorted(cameras, key=lambda c: -c[2])
    counts: dict[Shape, int] = {}
    for s in whole:
        counts[s] = counts.get(s, 0) + 1

    def step(j: int) -> float:
        n = dict(counts)
        for _, s, _ in order[:j]:
            n[s] = n.get(s, 0) + 1
        crops = sum(k for _, _, k in order[j:])
        return sum(costs.price(s, k) for s, k in n.items()) + costs.price(crop, crops)

    best, best_ms = 0, step(0)
    for j in range(1, len(order) + 1):
        ms = step(j)
        if ms < best_ms * (1 - SAVING):
            best, best_ms = j, ms
    return {name for name, _, _ in order[:best]}
