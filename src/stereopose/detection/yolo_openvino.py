"""YOLO-Pose on OpenVINO: the same ONNX model, letterbox, decode and NMS as the onnx backend.

OpenVINO (Intel's runtime, the one Frigate uses on CPUs and Intel GPUs) reads the ONNX model
itself; nothing is converted on disk. precision: "fp32" runs every layer in 32-bit floats
(the onnx backend's results to a fraction of a pixel); "bf16" lets the CPU run in bfloat16,
which OpenVINO chooses by itself on CPUs that have it (AVX512_BF16, AMX), faster and a little
less exact (benchmarks/results/backends.md). The device is "cpu", "gpu" (an Intel
GPU: "gpu.0", "gpu.1", ...) or "auto" (OpenVINO picks).
"""

from __future__ import annotations

import ast
import logging
import os
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from stereopose.detection.base import MAX_DET, Poses, detect_letterboxed, to_u8_blob
from stereopose.detection.models import ModelError, check_weights
from stereopose.detection.openvino_core import cpu_has_bf16, ov_core
from stereopose.detection.openvino_static import Key, StaticShapes
from stereopose.skeleton import NUM_JOINTS

if TYPE_CHECKING:
    import openvino as ov

logger = logging.getLogger(__name__)

# INFERENCE_PRECISION_HINT: an INT8 model (detection.int8_openvino) runs its quantised
# convolutions in integers and the rest, its pose head among them, in 32-bit floats, or in
# bfloat16 where the CPU has it
_HINTS = {"fp32": "f32", "bf16": "bf16", "int8": "f32"}
STREAMS = 2  # a CPU's batches split over this many inference streams


def ov_device(device: str) -> str:
    """OpenVINO's device name of a [detector] device."""
    d = device.strip().lower()
    if d == "cpu":
        return "CPU"
    if d == "auto":
        return "AUTO"
    if d == "gpu" or (d.startswith("gpu.") and d[4:].isdigit()):
        return d.upper()
    raise ModelError(f"device {device!r}: the openvino backend runs on cpu, gpu, gpu.N or auto")


class OpenVinoPoseDetector:
    """A YOLO pose model in ONNX (output (B, 56, N), no NMS inside) compiled by OpenVINO."""

    name = "openvino"
    max_det = MAX_DET  # people kept in one image at most

    def __init__(
        self,
        model: str | Path,
        imgsz: int = 640,
        conf: float = 0.25,
        iou: float = 0.7,
        device: str = "cpu",
        threads: int | None = None,
        precision: str = "fp32",
    ) -> None:
        self.model = check_weights(Path(model))
        if self.model.suffix not in (".onnx", ".xml"):
            raise ModelError(
                f"{self.model}: the openvino backend needs an .onnx model or OpenVINO's .xml"
            )
        if precision not in _HINTS:
            raise ModelError(
                f"precision {precision!r}: the openvino backend runs fp32, bf16 or int8 "
                "(OpenVINO's INT8 model)"
            )
        try:
            import openvino as ov

            core = ov_core()  # one for the process: see detection.openvino_core
        except ImportError:
            raise ModelError(
                "the openvino backend needs OpenVINO: pip install 'stereopose[openvino]'"
            ) from None
        self.device = _present_device(core, device, precision)
        net, meta = _read_pose_model(core, self.model)
        self.stride = int(meta.get("stride", 32))
        shape = net.inputs[0].get_partial_shape()
        self.dynamic = shape[2].is_dynamic or shape[3].is_dynamic
        self.fixed = None if self.dynamic else (shape[2].get_length(), shape[3].get_length())
        self.batch_dynamic = shape[0].is_dynamic
        source = net.clone()  # before its input's preparation: for models of one shape
        net = _taking_bgr_bytes(net)
        config: dict[str, str] = {"PERFORMANCE_HINT": "LATENCY"}
        n = threads or int(os.environ.get("STEREOPOSE_THREADS", 0))
        self.threads = n  # 0: the runtime's own choice
        if n and self.device == "CPU":
            config["INFERENCE_NUM_THREADS"] = str(n)
        if precision == "bf16" and self.device.startswith("GPU"):
            raise ModelError(
                "precision bf16 is for CPUs; an Intel GPU runs fp32 (or its own "
                "f16 with device auto)"
            )
        if self.device != "AUTO":  # a GPU runs f16 unless told
            config["INFERENCE_PRECISION_HINT"] = _HINTS[precision]
        if precision == "int8" and self.device == "CPU" and cpu_has_bf16():
            # its float layers in bfloat16 where the CPU has it (its check against fp32 is
            # made the same way, on this machine: on an AMD EPYC, 28 against 38 ms a batch of
            # four demo frames, the same joints within the check's noise)
            config["INFERENCE_PRECISION_HINT"] = "bf16"
        try:
            self.compiled = core.compile_model(net, self.device, config)
        except Exception as e:
            raise ModelError(
                f"{self.model}: OpenVINO cannot compile it for {self.device}: {e}"
            ) from None
        self.request = self.compiled.create_infer_request()
        # a batch split over two inference streams on a CPU (the same outputs, about 13 %
        # faster than one stream of the whole batch on 2 cores); one image: the one stream
        self._split: list = []
        split = {**config, "PERFORMANCE_HINT": "THROUGHPUT", "NUM_STREAMS": str(STREAMS)}
        if self.device == "CPU" and self.batch_dynamic and (n or os.cpu_count() or 1) >= 2:
            parallel = core.compile_model(net, self.device, split)
            self._split = [parallel.create_infer_request() for _ in range(STREAMS)]
        # the shapes met most compiled for themselves too (detection.openvino_static)
        self.static: StaticShapes | None = None
        if self.device == "CPU" and self.dynamic:
            configs = {"one": config, "split": split}
            self.static = StaticShapes(lambda key: _compile_static(source, key, configs))
        try:
            ran = self.compiled.get_property("INFERENCE_PRECISION_HINT").get_type_name()
        except Exception:  # a device without the property (AUTO before it chose)
            ran = "unknown"
        self.precision = precision
        self.runs_in = ran  # what the device compiled it to: f32, bf16, f16
        self.imgsz = imgsz
        self.conf, self.iou = conf, iou
        self.providers = [f"OpenVINO {ov.__version__.split('-')[0]} {self.device} {ran}"]
        logger.debug(
            "openvino: %s on %s, inference precision %s", self.model.name, self.device, ran
        )

    def _infer(self, blob: np.ndarray) -> np.ndarray:
        if len(blob) >= 2 and self._split:
            parts = [p for p in np.array_split(blob, len(self._split)) if len(p)]
            shapes = {p.shape[:3]: p for p in parts}  # each shape counted once a call
            own = {shape: self._own("split", p) for shape, p in shapes.items()}
            running = [(own[part.shape[:3]] or self._split)[i] for i, part in enumerate(parts)]
            for request, part in zip(running, parts, strict=True):
                request.start_async([part])
            for request in running:
                request.wait()
            return np.concatenate([r.get_output_tensor(0).data for r in running])
        # infer() gives its outputs as arrays of their own (share_outputs is off): no copy
        if self.batch_dynamic or len(blob) == 1:
            return np.asarray(self._one(blob).infer([blob])[0])
        return np.concatenate([np.asarray(self._one(b[None]).infer([b[None]])[0]) for b in blob])

    def _own(self, way: str, blob: np.ndarray) -> list | None:
        """The requests of the model compiled for blob's shape, if it has one (None: the
        dynamic model's)."""
        if self.static is None:
            return None
        n, h, w = blob.shape[:3]
        return self.static.requests((way, n, h, w))

    def _one(self, blob: np.ndarray) -> ov.InferRequest:
        own = self._own("one", blob)
        return own[0] if own else self.request

    def detect(self, images: Sequence[np.ndarray], imgsz: int | None = None) -> list[Poses]:
        return detect_letterboxed(self, images, imgsz, to_u8_blob)


def _present_device(core: ov.Core, device: str, precision: str) -> str:
    """OpenVINO's name of the [detector] device, which must be here and able to run
    `precision`."""
    name = ov_device(device)
    have = core.available_devices
    if name != "AUTO" and name.split(".")[0] not in {d.split(".")[0] for d in have}:
        raise ModelError(
            f"device {device!r}: OpenVINO finds no such device here "
            f"(available: {', '.join(have) or 'none'})"
        )
    if precision == "bf16" and name == "CPU" and not cpu_has_bf16():
        raise ModelError(
            "precision bf16: this CPU has no bfloat16 instructions (AVX512_BF16 or AMX); use fp32"
        )
    return name


def _read_pose_model(core: ov.Core, path: Path) -> tuple[ov.Model, dict[str, str]]:
    """The model at `path`, checked to be a COCO-17 pose model taking one image batch, and
    its metadata."""
    try:
        net = core.read_model(str(path))
    except Exception as e:  # OpenVINO raises its own RuntimeError kinds on a bad file
        raise ModelError(f"{path}: not a readable ONNX model: {e}") from None
    if len(net.inputs) != 1 or net.inputs[0].get_partial_shape().rank.get_length() != 4:
        raise ModelError(f"{path}: expected one image input (B, 3, H, W)")
    meta = _metadata(net)
    kpt = ast.literal_eval(meta["kpt_shape"]) if "kpt_shape" in meta else [NUM_JOINTS, 3]
    if list(kpt) != [NUM_JOINTS, 3]:
        raise ModelError(f"{path}: keypoint shape {kpt}, expected COCO-17 [17, 3]")
    return net, meta


def _compile_static(source: ov.Model, key: Key, configs: dict[str, dict[str, str]]) -> list:
    """The requests of `source` compiled for the one input shape of `key` (way, n, h, w),
    with the configuration of its way (one request; or one per stream, the batch split)."""
    way, n, h, w = key
    net = source.clone()
    net.reshape([n, 3, h, w])
    compiled = ov_core().compile_model(_taking_bgr_bytes(net), "CPU", configs[way])
    return [compiled.create_infer_request() for _ in range(STREAMS if way == "split" else 1)]


def _taking_bgr_bytes(net: ov.Model) -> ov.Model:
    """The model with its input's preparation compiled in: it takes the letterboxed BGR
    uint8 images as they are, (N, H, W, 3), and makes them RGB float in [0, 1] (N, 3, H, W)
    itself, fused into its first layers (about 6 ms less per step of 4 full-HD cameras on 2
    cores than NumPy's conversion; in fp32 the same joints to 0.001 px)."""
    import openvino as ov
    from openvino.preprocess import ColorFormat, PrePostProcessor

    ppp = PrePostProcessor(net)
    given = ppp.input()
    given.tensor().set_element_type(ov.Type.u8).set_layout(ov.Layout("NHWC")).set_color_format(
        ColorFormat.BGR
    )
    given.model().set_layout(ov.Layout("NCHW"))
    given.preprocess().convert_element_type(ov.Type.f32).convert_color(ColorFormat.RGB).scale(255.0)
    return ppp.build()


def _metadata(net: ov.Model) -> dict[str, str]:
    """The ONNX model's metadata (Ultralytics writes kpt_shape, stride) as OpenVINO keeps it."""
    out: dict[str, str] = {}
    try:
        info = net.get_rt_info()["framework"]
        for key in ("kpt_shape", "stride"):
            if key in info:
                out[key] = str(net.get_rt_info(["framework", key]).astype(str))
    except Exception:  # no metadata: the COCO-17 defaults
        return {}
    return out
