"""INT8 YOLO pose model for OpenVINO: post-training quantisation by NNCF, and its check.

`quantize` reads the ONNX model with OpenVINO, measures its activations' ranges on real frames
letterboxed as detection does, and writes OpenVINO's own model files (``.xml`` and ``.bin``) in
which the backbone's and neck's convolutions run in 8-bit integers (weights per channel,
symmetric; activations asymmetric: NNCF's "mixed" preset). Left in floats, as in the ONNX
Runtime model (detection.int8): the pose head (``/model.23/`` in an Ultralytics export), whose
outputs are keypoint offsets times the stride, where 8 bits put joints tens of pixels off; and
the inside of each SiLU (``x * sigmoid(x)``, the activation of every convolution block). Left to
itself, NNCF takes that product for a multiplication of two activations and quantises both its
inputs and the sigmoid's output: OpenVINO can then no longer fuse the SiLU into the
convolution before it, and runs it apart (on an AMD EPYC, 9 ms of a 34 ms batch of four demo
frames, and the model was no faster than bf16's). Quantised at the convolutions' inputs alone,
the same batch takes 26 ms, its joints a little nearer fp32's.

`check` says how far the quantised model's people are from the float model's on frames it was
not calibrated on: people matched by box overlap, the distance of the joints both see. The
check is written beside the model (``<stem>.json``); `make_detector`'s auto choice takes the
INT8 model only where its check passed (`accepted`) and it is faster on the CPU at hand.
`quantize_int8_openvino` does both for a model of the cache (what `stereopose models export`
runs), on the real recordings' frames.
"""

from __future__ import annotations

import json
import logging
import os
import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from stereopose.cache import cache_root
from stereopose.detection.base import Poses, letterbox_for, letterbox_image, to_blob
from stereopose.detection.models import (
    OV_CHECK_FRAMES,
    OV_INT8_FRAMES,
    ModelError,
    calibration_frames,
    check_weights,
    default_onnx,
    int8_videos,
    offline_environment,
    openvino_int8_path,
)
from stereopose.extras import require

if TYPE_CHECKING:
    import openvino as ov

    from stereopose.detection.base import PoseDetector

logger = logging.getLogger(__name__)

HEAD = r".*/model\.23/.*"  # the pose head of an Ultralytics export: left in floats
SILU = r".*/act/Mul"  # x * sigmoid(x) of each convolution block: left whole (see above)
# how the INT8 model is made: written in its check; a model made another way is stale, and
# `stereopose models export` (`make install`) makes it again
RECIPE = 2
# 2D joints of the INT8 model against the float model's, p95 over the check's frames, at most:
# OpenVINO bf16's on the real demo (5.6-5.9 px, benchmarks/results/backends.md), whose 3D
# joints are within 5 cm (p95) of fp32's
CHECK_P95_PX = 6.0
CHECK_MISSED = 0.02  # share of the float model's people the INT8 model may miss, at most
MATCH_IOU = 0.5
SEEN = 0.5  # a joint's confidence to be compared


def _blobs(frames: Sequence[np.ndarray], imgsz: int, stride: int) -> list[np.ndarray]:
    out = []
    for image in frames:
        lb = letterbox_for(image.shape[:2], imgsz, stride, auto=True)
        out.append(to_blob([letterbox_image(image, lb)]))
    return out


def quantize(src: Path, out: Path, frames: Sequence[np.ndarray], imgsz: int = 640) -> Path:
    """`src` (an ONNX YOLO pose model) quantised to OpenVINO's INT8 model `out` (.xml, its
    .bin beside it), its activations' ranges measured on `frames` (BGR uint8)."""
    import nncf
    import openvino as ov

    from stereopose.detection.openvino_core import ov_core

    if not frames:
        raise ValueError("quantisation needs at least one calibration frame")
    # not a line per operation left in floats: the "nncf" logger alone (nncf.set_log_level
    # also sets the level of every handler on that logger, which need not be its own)
    logging.getLogger("nncf").setLevel(logging.ERROR)
    model = ov_core().read_model(str(src))
    stride = _stride(model)
    blobs = _blobs(frames, imgsz, stride)
    quantized = nncf.quantize(
        model,
        nncf.Dataset(blobs),
        preset=nncf.QuantizationPreset.MIXED,
        subset_size=len(blobs),
        ignored_scope=nncf.IgnoredScope(patterns=[HEAD, SILU], types=["Sigmoid"], validate=False),
    )
    ov.save_model(quantized, str(out), compress_to_fp16=False)
    return out


def _stride(model: ov.Model) -> int:
    try:
        return int(str(model.get_rt_info(["framework", "stride"]).astype(str)))
    except Exception:  # no metadata: YOLO's largest stride
        return 32


def check(reference: PoseDetector, quantized: PoseDetector, frames: Sequence[np.ndarray]) -> dict:
    """How the people of detector `quantized` compare with those of `reference` (the float
    model) on `frames`: {"frames", "people", "missed", "extra", "joints", "median_px",
    "p95_px", "max_px", "accepted"}; accepted: p95 within CHECK_P95_PX and at most
    CHECK_MISSED of the reference's people missed."""
    dists: list[float] = []
    people = missed = extra = 0
    for image in frames:
        a = reference.detect([image])[0]
        b = quantized.detect([image])[0]
        pairs = _matched(a, b)
        people += len(a)
        missed += len(a) - len(pairs)
        extra += len(b) - len(pairs)
        for i, j in pairs:
            ka, kb = a.keypoints[i], b.keypoints[j]
            both = (ka[:, 2] >= SEEN) & (kb[:, 2] >= SEEN)
            dists += [float(x) for x in np.linalg.norm(ka[both, :2] - kb[both, :2], axis=1)]
    d = np.asarray(dists)
    p95 = float(np.quantile(d, 0.95)) if d.size else float("inf")
    return {
        "frames": len(frames),
        "people": people,
        "missed": missed,
        "extra": extra,
        "joints": int(d.size),
        "median_px": round(float(np.median(d)), 3) if d.size else None,
        "p95_px": round(p95, 3) if d.size else None,
        "max_px": round(float(d.max()), 3) if d.size else None,
        "p95_bound_px": CHECK_P95_PX,
        "accepted": bool(people and d.size)
        and p95 <= CHECK_P95_PX
        and missed <= CHECK_MISSED * people,
    }


def _matched(a: Poses, b: Poses) -> list[tuple[int, int]]:
    """People of a and b paired greedily by box overlap (IoU at least MATCH_IOU)."""
    pairs = sorted(
        ((_iou(a.boxes[i], b.boxes[j]), i, j) for i in range(len(a)) for j in range(len(b))),
        reverse=True,
    )
    used_a: set[int] = set()
    used_b: set[int] = set()
    out = []
    for iou, i, j in pairs:
        if iou < MATCH_IOU or i in used_a or j in used_b:
            continue
        used_a.add(i)
        used_b.add(j)
        out.append((i, j))
    return out


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    iw = min(a[2], b[2]) - max(a[0], b[0])
    ih = min(a[3], b[3]) - max(a[1], b[1])
    inter = max(iw, 0.0) * max(ih, 0.0)
    union = (a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - inter
    return float(inter / union) if union > 0 else 0.0


def current(model: Path) -> bool:
    """Whether the INT8 model at `model` (.xml) is there with its check, made by this
    RECIPE (a model made by an older one is made again)."""
    return model.is_file() and made_now(read_check(model))


def made_now(check: dict | None) -> bool:
    """Whether an INT8 model's check says it was made by this RECIPE."""
    return check is not None and check.get("recipe") == RECIPE


def check_path(model: Path) -> Path:
    """Where the check of the INT8 model at `model` (.xml) is kept."""
    return model.with_suffix(".json")


def read_check(model: Path) -> dict | None:
    """The check written beside the INT8 model at `model`; None if there is none or it is
    unreadable (the model is then not taken by the auto choice)."""
    try:
        found = json.loads(check_path(model).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return found if isinstance(found, dict) else None


def quantize_int8_openvino(
    model: Path | None = None, out: Path | None = None, cache: Path | None = None
) -> Path:
    """OpenVINO's INT8 model of an ONNX pose model (default: the cache's yolo11n-pose),
    quantised by NNCF on frames of the real recordings and checked against the float model on
    others (detection.int8_openvino); its .xml path (default `openvino_int8_path`)."""
    src = check_weights(Path(model) if model is not None else default_onnx(cache))
    if src.suffix != ".onnx":
        raise ModelError(f"{src}: INT8 quantisation needs an ONNX model (.onnx)")
    out = Path(out) if out is not None else openvino_int8_path(cache)
    if out.suffix != ".xml":
        raise ModelError(f"{out}: OpenVINO's INT8 model is written as an .xml file (and .bin)")
    for module, extra in (("openvino", "openvino"), ("nncf", "int8")):
        require(
            module,
            extra,
            f"INT8 quantisation of {src.name} for OpenVINO",
            f"or copy {out.name}, {out.with_suffix('.bin').name} and "
            f"{out.with_suffix('.json').name} from an install that has made them to {out.parent}",
        )
    videos = int8_videos(cache)
    if not videos:
        raise ModelError(
            f"INT8 quantisation needs calibration frames: the real recordings are not in "
            f"{cache_root(cache)} (`python -m stereopose.io.pose2sim_data` unpacks them once)"
        )
    from stereopose.detection.yolo_openvino import OpenVinoPoseDetector

    offline_environment(cache)
    out.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=out.parent, prefix=".int8.") as tmp:
        staged = quantize(src, Path(tmp) / out.name, calibration_frames(videos, OV_INT8_FRAMES))
        frames = calibration_frames(videos, OV_CHECK_FRAMES, phase=0.5)
        found = check(
            OpenVinoPoseDetector(src, precision="fp32"),
            OpenVinoPoseDetector(staged, precision="int8"),
            frames,
        )
        found["model"] = src.name
        found["recipe"] = RECIPE
        staged.with_suffix(".json").write_text(json.dumps(found, indent=1) + "\n", "utf-8")
        for suffix in (".bin", ".json", ".xml"):  # the .xml last: its presence says complete
            os.replace(staged.with_suffix(suffix), out.with_suffix(suffix))
    logger.info(
        "OpenVINO INT8 model written to %s: joints p95 %s px from the float model's (%s)",
        out,
        found["p95_px"],
        "accepted" if found["accepted"] else f"over the {found['p95_bound_px']} px bound",
    )
    return out
