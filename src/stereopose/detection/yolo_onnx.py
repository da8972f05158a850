"""YOLO-Pose on ONNX Runtime: letterbox, one batched inference per image size, decode, NMS."""

from __future__ import annotations

import ast
import logging
import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from stereopose.detection.base import Poses, detect_letterboxed
from stereopose.detection.models import ModelError, check_weights, offline_environment
from stereopose.skeleton import NUM_JOINTS

logger = logging.getLogger(__name__)


def _providers(device: str, available: list[str]) -> list[str]:
    if device == "cpu":
        return ["CPUExecutionProvider"]
    if device in ("cuda", "gpu") or device.startswith("cuda:") or device.isdigit():
        if "CUDAExecutionProvider" not in available:
            raise ModelError(
                f"device {device!r}: this ONNX Runtime has no CUDA provider "
                f"(available: {', '.join(available)})"
            )
        return ["CUDAExecutionProvider", "CPUExecutionProvider"]
    if device == "auto":
        gpu = [p for p in ("CUDAExecutionProvider",) if p in available]
        return [*gpu, "CPUExecutionProvider"]
    raise ModelError(f"device {device!r}: expected cpu, cuda, cuda:N or auto")


class OnnxPoseDetector:
    """A YOLO pose model exported to ONNX (output (B, 56, N), no NMS inside)."""

    name = "onnx"

    def __init__(
        self,
        model: str | Path,
        imgsz: int = 640,
        conf: float = 0.25,
        iou: float = 0.7,
        max_det: int = 300,
        device: str = "cpu",
        threads: int | None = None,
    ) -> None:
        offline_environment()
        self.model = check_weights(Path(model))
        if self.model.suffix != ".onnx":
            raise ModelError(f"{self.model}: the onnx backend needs an .onnx model")
        import onnxruntime as ort

        options = ort.SessionOptions()
        options.intra_op_num_threads = threads or int(os.environ.get("STEREOPOSE_THREADS", 0))
        options.log_severity_level = 3
        providers = _providers(device, ort.get_available_providers())
        try:
            self.session = ort.InferenceSession(str(self.model), options, providers=providers)
        except Exception as e:  # onnxruntime raises its own exception types on a bad file
            raise ModelError(f"{self.model}: not a readable ONNX model: {e}") from None
        inp = self.session.get_inputs()
        outs = self.session.get_outputs()
        if len(inp) != 1 or len(inp[0].shape) != 4 or not outs:
            raise ModelError(f"{self.model}: expected one image input (B, 3, H, W)")
        meta = self.session.get_modelmeta().custom_metadata_map
        kpt = ast.literal_eval(meta["kpt_shape"]) if "kpt_shape" in meta else [NUM_JOINTS, 3]
        if list(kpt) != [NUM_JOINTS, 3]:
            raise ModelError(f"{self.model}: keypoint shape {kpt}, expected COCO-17 [17, 3]")
        self.stride = int(meta.get("stride", 32))
        self.input_name = inp[0].name
        shape = inp[0].shape
        self.dynamic = not all(isinstance(d, int) for d in shape[2:])
        self.fixed = None if self.dynamic else (int(shape[2]), int(shape[3]))
        self.batch_dynamic = not isinstance(shape[0], int)
        self.imgsz = imgsz
        self.conf, self.iou, self.max_det = conf, iou, max_det
        self.providers = self.session.get_providers()

    def _infer(self, blob: np.ndarray) -> np.ndarray:
        if self.batch_dynamic or len(blob) == 1:
            return self.session.run(None, {self.input_name: blob})[0]
        return np.concatenate([self.session.run(None, {self.input_name: b[None]})[0] for b in blob])

    def detect(self, images: Sequence[np.ndarray]) -> list[Poses]:
        return detect_letterboxed(self, images)
