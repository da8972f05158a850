"""INT8 quantisation of a YOLO pose ONNX model with ONNX Runtime (static, QDQ format).

Only the convolutions inside the network are quantised (weights per channel, signed;
activations unsigned, their ranges measured on calibration frames letterboxed as detection
does). The pose head stays in floats, its convolutions and its decoding: a keypoint is an
offset from its anchor times the stride (up to 32 input pixels per unit), and 8-bit features
there put joints tens of pixels off (measured on the demo), where the backbone's lose nothing
that shows.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import onnx
from onnxruntime.quantization import CalibrationDataReader

from stereopose.detection.base import letterbox_for, letterbox_image, to_blob

logger = logging.getLogger(__name__)


class _Frames(CalibrationDataReader):
    """ONNX Runtime's CalibrationDataReader over letterboxed frames."""

    def __init__(self, name: str, frames: list[np.ndarray], imgsz: int, stride: int) -> None:
        blobs = []
        for image in frames:
            lb = letterbox_for(image.shape[:2], imgsz, stride, auto=True)
            blobs.append(to_blob([letterbox_image(image, lb)]))
        self._items = iter([{name: b} for b in blobs])

    # ONNX Runtime's annotation leaves out the None that ends the frames, as its docs give it
    def get_next(self) -> dict | None:  # pyright: ignore[reportIncompatibleMethodOverride]
        return next(self._items, None)


def quantize(src: Path, work: Path, frames: list[np.ndarray], imgsz: int = 640) -> Path:
    """`src` quantised into the folder `work`; the quantised file's path."""
    from onnxruntime.quantization import (
        CalibrationMethod,
        QuantFormat,
        QuantType,
        quantize_static,
    )
    from onnxruntime.quantization.shape_inference import quant_pre_process

    if not frames:
        raise ValueError("quantisation needs at least one calibration frame")
    model = onnx.load(str(src))
    meta = {p.key: p.value for p in model.metadata_props}
    name = model.graph.input[0].name
    raw = _raw_outputs(model)
    pre = work / "pre.onnx"
    quant_pre_process(str(src), str(pre), skip_symbolic_shape=True)
    out = work / "int8.onnx"
    quantize_static(
        str(pre),
        str(out),
        _Frames(name, frames, imgsz, int(meta.get("stride", 32))),
        quant_format=QuantFormat.QDQ,
        per_channel=True,
        activation_type=QuantType.QUInt8,
        weight_type=QuantType.QInt8,
        op_types_to_quantize=["Conv"],
        calibrate_method=CalibrationMethod.MinMax,
        nodes_to_exclude=raw,
    )
    quantized = onnx.load(str(out))
    have = {p.key for p in quantized.metadata_props}
    for key, value in meta.items():  # kpt_shape, stride, names: the detector reads them
        if key not in have:
            quantized.metadata_props.add(key=key, value=value)
    onnx.save(quantized, str(out))
    return out


def _raw_outputs(model: onnx.ModelProto) -> list[str]:
    """The head's convolutions: those in the module (name prefix, "/model.23/" in an
    Ultralytics export) of the convolutions no activation (SiLU: Sigmoid, then Mul) follows."""
    consumers: dict[str, set[str]] = {}
    for node in model.graph.node:
        for name in node.input:
            consumers.setdefault(name, set()).add(node.op_type)
    convs = [n for n in model.graph.node if n.op_type == "Conv"]
    raw = [n.name for n in convs if "Sigmoid" not in consumers.get(n.output[0], set())]
    heads = {"/".join(name.split("/")[:2]) + "/" for name in raw if name.count("/") >= 2}
    return [n.name for n in convs if n.name in raw or any(n.name.startswith(h) for h in heads)]
