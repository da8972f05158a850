"""Person detection: YOLO-Pose backends and readers/writers of 2D keypoint files.

``make_detector`` builds a backend from local model files only: ``onnx`` (ONNX Runtime, the
default), ``openvino`` (OpenVINO, on the same ONNX model) or ``ultralytics`` (PyTorch). None
imports anything heavy until it is asked for. ``precision = "int8"`` (onnx) runs the ONNX model
quantised to 8-bit integers (detection.models); ``"bf16"`` (openvino on a CPU that has it) runs
in bfloat16; ``"fp16"`` (onnx with device tensorrt) lets TensorRT run in half precision. The onnx
backend's device is cpu, cuda[:N], tensorrt[:N] or auto (detection.yolo_onnx).
"""

from __future__ import annotations

from pathlib import Path

from stereopose.detection.base import PoseDetector, Poses
from stereopose.detection.models import (
    ModelError,
    check_weights,
    default_int8,
    default_onnx,
    default_weights,
    export_onnx,
    models_dir,
)

BACKENDS = ("onnx", "openvino", "ultralytics")
PRECISIONS = ("fp32", "bf16", "int8", "fp16")

__all__ = ["BACKENDS", "ModelError", "PoseDetector", "Poses", "make_detector"]


def make_detector(
    backend: str = "onnx",
    model: str | Path | None = None,
    imgsz: int = 640,
    conf: float = 0.25,
    iou: float = 0.7,
    device: str = "cpu",
    threads: int | None = None,
    precision: str = "fp32",
) -> PoseDetector:
    """A pose detector. model: a local .onnx or .pt file (default: yolo11n-pose from the cache).

    The onnx and openvino backends given a .pt file export it to ONNX once, into the cache.
    precision "int8" (onnx only): the model quantised once into the cache (``<stem>-int8.onnx``
    beside it; a model already quantised is taken as it is); "bf16": openvino only; "fp16":
    onnx on device tensorrt only.
    """
    if precision not in PRECISIONS:
        raise ModelError(f"precision must be one of {', '.join(PRECISIONS)}, got {precision!r}")
    if precision == "int8" and backend != "onnx":
        # OpenVINO runs ONNX Runtime's INT8 model, but loses people with it (person scores
        # about 0.3 where ONNX Runtime gives 0.9: benchmarks/results/backends.md)
        raise ModelError(f"precision int8 needs the onnx backend, not {backend!r}")
    if precision == "bf16" and backend != "openvino":
        raise ModelError(f"precision bf16 needs the openvino backend, not {backend!r}")
    if precision == "fp16" and backend != "onnx":
        # OpenVINO on an Intel GPU runs f16 by itself (device auto); fp16 is TensorRT's
        raise ModelError(
            f"precision fp16 needs the onnx backend (device tensorrt), not {backend!r}"
        )
    if not isinstance(imgsz, int) or imgsz < 32 or imgsz % 32:
        raise ModelError(f"imgsz must be a positive multiple of 32, got {imgsz}")
    if not 0 <= conf <= 1 or not 0 <= iou <= 1:
        raise ModelError(f"conf and iou must be in [0, 1], got {conf} and {iou}")
    kwargs = {"imgsz": imgsz, "conf": conf, "iou": iou, "device": device, "threads": threads}
    if backend in ("onnx", "openvino"):
        if model is None:
            path = default_onnx()
        else:
            path = check_weights(Path(model))
            if path.suffix == ".pt":
                onnx = models_dir() / f"{path.stem}.onnx"
                path = onnx if onnx.is_file() else export_onnx(path, onnx)
        if precision == "int8":
            path = _int8(path, model is None)
        if backend == "openvino":
            from stereopose.detection.yolo_openvino import OpenVinoPoseDetector

            return OpenVinoPoseDetector(path, precision=precision, **kwargs)
        from stereopose.detection.yolo_onnx import OnnxPoseDetector

        return OnnxPoseDetector(path, precision=precision, **kwargs)
    if backend == "ultralytics":
        from stereopose.detection.yolo_ultralytics import UltralyticsPoseDetector

        return UltralyticsPoseDetector(model if model is not None else default_weights(), **kwargs)
    raise ModelError(f"unknown detector backend {backend!r}; expected one of {', '.join(BACKENDS)}")


def _int8(path: Path, default: bool) -> Path:
    """The INT8 model of the ONNX model at `path`, quantised once (next to it, or for a user's
    model into the cache, so that no folder of theirs is written)."""
    from stereopose.detection.models import INT8_SUFFIX, quantize_int8

    if default:
        return default_int8()
    if path.stem.endswith(INT8_SUFFIX):
        return path
    target = models_dir() / f"{path.stem}{INT8_SUFFIX}.onnx"
    return target if target.is_file() else quantize_int8(path, target)
