"""Whether the auto choice takes OpenVINO's INT8 model on this machine: the model made, its
check passed, and faster here than the float model auto would run otherwise.

Its speed is measured once per machine (the CPU's name, the OpenVINO version, the model file
and what it is weighed against), a few batches of four frames of the demo's size through each
model, and kept in ``<cache>/models/int8_speed.json``; a new model file or another CPU is
measured again.
"""

from __future__ import annotations

import json
import logging
import os
import statistics
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

logger = logging.getLogger(__name__)

MIN_SPEEDUP = 1.15  # INT8 taken where it is at least this much faster than the float model
BATCHES = 6  # timed batches of each model (after one to warm up)
FRAME = (1088, 1920, 3)  # the demo's portrait full-HD frames: what a step of cameras holds
SPEED_FILE = "int8_speed.json"
KEPT = 16  # machines and model files whose figure is kept, the newest


@dataclass(frozen=True)
class Int8Found:
    """What is known of OpenVINO's INT8 model here: its file (None: not made), its check
    against the float model (None: none readable), and how many times the float model's speed
    it runs at on this CPU (None: not measured)."""

    path: Path | None
    check: dict | None
    speedup: float | None
    stale: bool = False  # made by an older recipe (detection.int8_openvino.RECIPE)

    def refusal(self, against: str) -> str | None:
        """Why the auto choice does not take it (None: it does); against: the float model it
        is weighed against, as said to the user ("OpenVINO bf16")."""
        if self.path is None:
            return "no INT8 model made (`stereopose models export --int8`)"
        if self.stale:
            return (
                "the INT8 model was made by an older recipe "
                "(`stereopose models export --openvino-int8 --force` makes it again)"
            )
        if not self.check or not self.check.get("accepted"):
            p95 = (self.check or {}).get("p95_px")
            bound = (self.check or {}).get("p95_bound_px")
            return (
                f"the INT8 model's joints are {p95} px (p95) from fp32's, over the {bound} px bound"
                if p95 is not None and bound is not None
                else "the INT8 model has no passed check against fp32"
            )
        if self.speedup is None:
            return "the INT8 model's speed could not be measured here"
        if self.speedup < MIN_SPEEDUP:
            return (
                f"the INT8 model runs at {self.speedup:.2f}x {against}'s speed on this CPU "
                f"(under {MIN_SPEEDUP}x)"
            )
        return None


def find_int8(precision: str, measure: bool = True) -> Int8Found:
    """The default INT8 model's state here, weighed against the float model run by OpenVINO
    in `precision` (fp32 or bf16). measure: time it now if this machine has no figure yet."""
    from stereopose.detection.int8_openvino import made_now, read_check
    from stereopose.detection.models import openvino_int8_path

    path = openvino_int8_path()
    if not path.is_file() or not path.with_suffix(".bin").is_file():
        return Int8Found(None, None, None)
    check = read_check(path)
    if check and not made_now(check):
        return Int8Found(path, check, None, stale=True)
    if not check or not check.get("accepted"):
        return Int8Found(path, check, None)
    return Int8Found(path, check, speedup(path, precision, measure))


def speedup(int8: Path, precision: str, measure: bool = True) -> float | None:
    """How many times faster the INT8 model at `int8` runs than the float model it was made
    from in `precision`, on this CPU: kept from an earlier measure, or measured now."""
    from stereopose.detection.openvino_core import ov_core

    try:
        core = ov_core()
        import openvino as ov

        cpu = str(core.get_property("CPU", "FULL_DEVICE_NAME"))
        stat = int8.stat()
        key = f"{cpu}|{ov.__version__}|{int8.name}:{stat.st_size}:{stat.st_mtime_ns}|{precision}"
    except Exception as e:  # a broken install or a file gone: not measured, not taken
        logger.warning("int8: cannot weigh %s here: %s", int8, e)
        return None
    store = int8.parent / SPEED_FILE
    known = _read(store)
    if key in known:
        return float(known[key])
    if not measure:
        return None
    try:
        found = _measure(int8, precision)
    except Exception as e:  # the model does not run here: not taken
        logger.warning("int8: %s does not run on this CPU: %s", int8, e)
        return None
    known.pop(key, None)
    known[key] = round(found, 3)
    _write(store, dict(list(known.items())[-KEPT:]))
    logger.info("int8: %s runs at %.2fx the speed of %s here", int8.name, found, precision)
    return found


def _measure(int8: Path, precision: str) -> float:
    """The float model's time for a batch of four frames over the INT8 model's (median)."""
    from stereopose.detection.int8_openvino import read_check
    from stereopose.detection.models import models_dir
    from stereopose.detection.yolo_openvino import OpenVinoPoseDetector

    src = models_dir() / str((read_check(int8) or {}).get("model", ""))
    if not src.is_file():
        raise FileNotFoundError(f"{src}: the float model the INT8 model was made from")
    rng = np.random.default_rng(0)
    batch = [rng.integers(0, 256, FRAME, dtype=np.uint8) for _ in range(4)]
    times = {}
    for name, path, prec in (("float", src, precision), ("int8", int8, "int8")):
        det = OpenVinoPoseDetector(path, precision=prec)
        det.detect(batch)
        runs = []
        for _ in range(BATCHES):
            t0 = time.perf_counter()
            det.detect(batch)
            runs.append(time.perf_counter() - t0)
        times[name] = statistics.median(runs)
    return times["float"] / times["int8"]


def _read(path: Path) -> dict:
    try:
        found = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}
    return found if isinstance(found, dict) else {}


def _write(path: Path, known: dict) -> None:
    """Written whole, then renamed over the old file (two processes at once: one wins)."""
    tmp = path.with_name(f".{path.name}.{os.getpid()}")
    try:
        tmp.write_text(json.dumps(known, indent=1) + "\n", encoding="utf-8")
        os.replace(tmp, path)
    except OSError as e:  # a read-only cache: measured again next time
        logger.warning("int8: cannot keep the speed figure in %s: %s", path, e)
