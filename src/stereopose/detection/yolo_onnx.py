"""YOLO-Pose on ONNX Runtime: letterbox, one batched inference per image size, decode, NMS.

The device is "cpu", "cuda" ("cuda:N", or "N", for the N-th GPU), "tensorrt" ("tensorrt:N":
TensorRT, with CUDA for what TensorRT does not take) or "auto" (CUDA if there is one, else the
CPU). The GPU devices need ONNX Runtime's GPU package (``onnxruntime-gpu`` in place of
``onnxruntime``; TensorRT's libraries besides for tensorrt); the runtime install stays without
PyTorch. TensorRT builds its engine once, for batches of 1 to ``max_batch`` images up to imgsz
square, and keeps it in ``<cache>/models/trt/`` so that a restart loads it; precision "fp16"
(tensorrt only) lets TensorRT run in half precision.
"""

from __future__ import annotations

import ast
import contextlib
import io
import logging
import os
from collections.abc import Sequence
from pathlib import Path
from types import ModuleType
from typing import TYPE_CHECKING

import numpy as np

from stereopose.detection.base import MAX_DET, Poses, detect_letterboxed
from stereopose.detection.models import ModelError, check_weights, models_dir, offline_environment
from stereopose.skeleton import NUM_JOINTS

if TYPE_CHECKING:
    import onnxruntime as ort

logger = logging.getLogger(__name__)

CPU, CUDA, TENSORRT = "CPUExecutionProvider", "CUDAExecutionProvider", "TensorrtExecutionProvider"
MAX_BATCH = 32  # images per inference; a step of more cameras runs in chunks of this many
PRECISIONS = ("fp32", "fp16", "int8")  # int8: the model file is the quantised one
_NAMES = {CUDA: "CUDA", TENSORRT: "TensorRT"}
_GPU_PACKAGE = (
    "GPU runs need ONNX Runtime's GPU package in place of the CPU one (pip uninstall "
    "onnxruntime; pip install onnxruntime-gpu)"
)
_GPU_LIBRARIES = (
    "it needs a GPU, its driver, and the CUDA and cuDNN libraries this onnxruntime-"
    "gpu is built for (pip install 'onnxruntime-gpu[cuda,cudnn]')"
)
_TRT_LIBRARIES = (
    "TensorRT also needs its libraries, of the major version ONNX Runtime is built "
    "for (onnxruntime-gpu 1.31: TensorRT 10, pip install --extra-index-url "
    "https://pypi.nvidia.com 'tensorrt-cu13-libs==10.*'; or their folder in "
    "LD_LIBRARY_PATH)"
)

Provider = tuple[str, dict[str, str]]


def parse_device(device: str) -> tuple[str, int]:
    """("cpu" | "cuda" | "tensorrt" | "auto", GPU index) of a [detector] device."""
    d = device.strip().lower()
    if d in ("cpu", "auto"):
        return d, 0
    if d.isdigit():
        return "cuda", int(d)
    kind, sep, index = d.partition(":")
    if kind == "gpu":
        kind = "cuda"
    if kind in ("cuda", "tensorrt") and (index.isdigit() or not sep):
        return kind, int(index or 0)
    raise ModelError(f"device {device!r}: expected cpu, cuda, cuda:N, tensorrt, tensorrt:N or auto")


def _providers(
    device: str,
    available: Sequence[str],
    precision: str = "fp32",
    engine_cache: Path | None = None,
    profile: dict[str, str] | None = None,
) -> list[Provider]:
    """ONNX Runtime's providers, each with its options, for a device, in order of preference.

    available: what this ONNX Runtime has (``get_available_providers()``). engine_cache: the
    folder TensorRT keeps its engines and timing cache in; profile: its trt_profile_* shapes.
    """
    if precision not in PRECISIONS:
        raise ModelError(f"precision {precision!r}: the onnx backend runs {', '.join(PRECISIONS)}")
    kind, index = parse_device(device)
    if precision == "fp16" and kind != "tensorrt":
        raise ModelError(
            f"precision fp16 runs on TensorRT (device tensorrt or tensorrt:N), "
            f"not on device {device!r}"
        )
    cpu: Provider = (CPU, {})
    cuda: Provider = (CUDA, {"device_id": str(index)})
    if kind == "cpu":
        return [cpu]
    if kind == "auto":
        return [cuda, cpu] if CUDA in available else [cpu]
    wanted = [TENSORRT, CUDA] if kind == "tensorrt" else [CUDA]
    missing = [p for p in wanted if p not in available]
    if missing:
        raise ModelError(
            f"device {device!r}: this ONNX Runtime has no "
            f"{' or '.join(_NAMES[p] for p in missing)} provider (available: "
            f"{', '.join(available) or 'none'}); {_GPU_PACKAGE}"
        )
    if kind == "cuda":
        return [cuda, cpu]
    trt = {
        "device_id": str(index),
        "trt_fp16_enable": str(precision == "fp16"),
        "trt_engine_cache_enable": "True",
        "trt_timing_cache_enable": "True",
    }
    if engine_cache is not None:
        trt["trt_engine_cache_path"] = trt["trt_timing_cache_path"] = str(engine_cache)
    return [(TENSORRT, {**trt, **(profile or {})}), cuda, cpu]


def trt_profile(name: str, shape: Sequence, imgsz: int, max_batch: int) -> dict[str, str]:
    """TensorRT's optimisation profile of the (B, 3, H, W) input `name`: batches of 1 to
    max_batch, images of one stride to imgsz square, where the model leaves them dynamic.

    One engine then serves every step; without it TensorRT builds for the first shape seen and
    rebuilds, for tens of seconds, each time a larger batch or image comes.
    """
    if len(shape) != 4:
        raise ModelError(f"input {name}: expected (B, 3, H, W), got {list(shape)}")
    fixed = [d if isinstance(d, int) and d > 0 else None for d in shape]
    if all(fixed):
        return {}

    def dims(b: int, hw: int) -> str:
        return f"{name}:{fixed[0] or b}x{fixed[1] or 3}x{fixed[2] or hw}x{fixed[3] or hw}"

    return {
        "trt_profile_min_shapes": dims(1, 32),
        "trt_profile_opt_shapes": dims(min(max_batch, 8), imgsz),
        "trt_profile_max_shapes": dims(max_batch, imgsz),
    }


def _preload_gpu_libraries(ort: ModuleType, tensorrt: bool) -> None:
    """CUDA and cuDNN from their pip packages (onnxruntime-gpu[cuda,cudnn]) and TensorRT's from
    tensorrt-cu12-libs, where the loader would not find them; what is missing is left to the
    session's own loading (and its error)."""
    said = io.StringIO()
    with contextlib.redirect_stdout(said):
        try:
            if hasattr(ort, "preload_dlls"):
                ort.preload_dlls()
        except Exception as e:  # best effort: the session says what it could not load
            logger.debug("preloading CUDA libraries: %s", e)
    if said.getvalue().strip():
        logger.debug("preloading CUDA libraries: %s", said.getvalue().strip())
    if not tensorrt:
        return
    import ctypes
    import importlib.util

    spec = importlib.util.find_spec("tensorrt_libs")
    for folder in (spec.submodule_search_locations or []) if spec else []:
        for pattern in ("libnvinfer.so.*", "libnvinfer_plugin.so.*", "libnvonnxparser.so.*"):
            for lib in sorted(Path(folder).glob(pattern)):
                try:
                    ctypes.CDLL(str(lib), mode=ctypes.RTLD_GLOBAL)
                except OSError as e:
                    logger.debug("preloading %s: %s", lib, e)


class OnnxPoseDetector:
    """A YOLO pose model exported to ONNX (output (B, 56, N), no NMS inside).

    ``providers``: what the session really runs on, best first (ONNX Runtime falls back
    silently; a device asked for by name that did not start is a ModelError instead).
    """

    name = "onnx"
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
        max_batch: int = MAX_BATCH,
    ) -> None:
        offline_environment()
        self.model = check_weights(Path(model))
        if self.model.suffix != ".onnx":
            raise ModelError(f"{self.model}: the onnx backend needs an .onnx model")
        if not isinstance(max_batch, int) or max_batch < 1:
            raise ModelError(f"max_batch must be a positive integer, got {max_batch!r}")
        import onnxruntime as ort

        kind, _ = parse_device(device)
        available = ort.get_available_providers()
        # an engine per model, precision and profile, never one built for other shapes
        half = "-fp16" if precision == "fp16" else ""
        engines = models_dir() / "trt" / f"{self.model.stem}{half}-{imgsz}-b{max_batch}"
        providers = _providers(device, available, precision, engines)  # errors before loading
        options = ort.SessionOptions()
        options.intra_op_num_threads = threads or int(os.environ.get("STEREOPOSE_THREADS", 0))
        self.threads = options.intra_op_num_threads  # 0: the runtime's own choice
        options.log_severity_level = 3
        if providers[0][0] != CPU:
            _preload_gpu_libraries(ort, tensorrt=kind == "tensorrt")
        self.session = self._session(ort, options, [(CPU, {})])
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
        self.conf, self.iou = conf, iou
        self.device, self.precision, self.max_batch = device, precision, max_batch
        if providers[0][0] != CPU:
            if kind == "tensorrt":
                try:
                    engines.mkdir(parents=True, exist_ok=True)
                except OSError as e:
                    raise ModelError(f"{engines}: TensorRT's engine folder: {e}") from None
                profile = trt_profile(self.input_name, shape, imgsz, max_batch)
                providers = _providers(device, available, precision, engines, profile)
            self.session = self._session(ort, options, providers)
        self.providers = self.session.get_providers()
        if self.providers[0] != providers[0][0]:
            if kind != "auto":
                raise ModelError(
                    f"device {device!r}: ONNX Runtime {ort.__version__} could not start its "
                    f"{_NAMES.get(providers[0][0], providers[0][0])} provider (the session runs "
                    f"on {', '.join(self.providers)}): {_GPU_LIBRARIES}"
                    + (f"; {_TRT_LIBRARIES}" if kind == "tensorrt" else "")
                )
            logger.warning("onnx: device auto runs on %s", ", ".join(self.providers))
        logger.info("onnx: %s on %s (%s)", self.model.name, ", ".join(self.providers), precision)

    def _session(
        self, ort: ModuleType, options: ort.SessionOptions, providers: list[Provider]
    ) -> ort.InferenceSession:
        try:
            return ort.InferenceSession(
                str(self.model),
                options,
                providers=[p for p, _ in providers],
                provider_options=[o for _, o in providers],
            )
        except Exception as e:  # onnxruntime raises its own exception types on a bad file
            if providers[0][0] == CPU:
                raise ModelError(f"{self.model}: not a readable ONNX model: {e}") from None
            raise ModelError(
                f"{self.model}: ONNX Runtime cannot run it on {_NAMES[providers[0][0]]}: {e}"
            ) from None

    def _infer(self, blob: np.ndarray) -> np.ndarray:
        """(B, 3, H, W) -> (B, 56, N): in one run, or in runs of max_batch images (one each for
        a model of fixed batch)."""
        step = self.max_batch if self.batch_dynamic else 1
        if len(blob) <= step:
            return np.asarray(self.session.run(None, {self.input_name: blob})[0])
        return np.concatenate(
            [
                np.asarray(self.session.run(None, {self.input_name: blob[k : k + step]})[0])
                for k in range(0, len(blob), step)
            ]
        )

    def detect(self, images: Sequence[np.ndarray], imgsz: int | None = None) -> list[Poses]:
        return detect_letterboxed(self, images, imgsz)
