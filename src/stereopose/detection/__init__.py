"""Person detection: YOLO-Pose backends and readers/writers of 2D keypoint files.

``make_detector`` builds a backend from local model files only: ``onnx`` (ONNX Runtime),
``openvino`` (OpenVINO, on the same ONNX model) or ``ultralytics`` (PyTorch); ``auto`` (the
default) chooses, on the machine it runs on, the fastest of them within the accuracy the docs
set (``choose``: OpenVINO in bfloat16 on a CPU with bfloat16 instructions, 2.2x faster with 3D
joints p95 within 5 cm of fp32's; ONNX Runtime fp32 elsewhere). None imports anything heavy
until it is asked for. ``precision = "int8"`` (onnx) runs the ONNX model
quantised to 8-bit integers (detection.models); ``"bf16"`` (openvino on a CPU that has it) runs
in bfloat16; ``"fp16"`` (onnx with device tensorrt) lets TensorRT run in half precision. The onnx
backend's device is cpu, cuda[:N], tensorrt[:N] or auto (detection.yolo_onnx).
"""

from __future__ import annotations

import importlib.util
import logging
from dataclasses import dataclass
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
AUTO = "auto"

__all__ = [
    "AUTO",
    "BACKENDS",
    "Choice",
    "ModelError",
    "PoseDetector",
    "Poses",
    "choice_of",
    "choose",
    "make_detector",
]

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class Choice:
    """The backend and precision a detector runs, and why (said once at start, and in
    status.json and the report)."""

    backend: str
    precision: str
    why: str

    def as_dict(self) -> dict[str, str]:
        return {"backend": self.backend, "precision": self.precision, "why": self.why}

    def __str__(self) -> str:
        return f"{self.backend} {self.precision} ({self.why})"


def choice_of(detector: object) -> Choice | None:
    """What make_detector chose for `detector`, and why; None for a detector made otherwise
    (a wrapper, a test's own)."""
    choice = getattr(detector, "choice", None)
    return choice if isinstance(choice, Choice) else None


def cpu_bf16() -> bool | None:
    """Whether OpenVINO finds bfloat16 instructions on this CPU (AVX512_BF16 or AMX); None
    when OpenVINO is not installed."""
    if importlib.util.find_spec("openvino") is None:
        return None
    try:
        from stereopose.detection.openvino_core import cpu_has_bf16

        return cpu_has_bf16()
    except Exception as e:  # a broken install: as if it were not there
        logger.warning("openvino: cannot read the CPU's capabilities: %s", e)
        return None


_ASK = object()  # choose(): find out here whether the CPU has bfloat16


def choose(
    backend: str = AUTO,
    precision: str = AUTO,
    device: str = "cpu",
    *,
    bf16: object = _ASK,
    int8: object = _ASK,
) -> Choice:
    """The backend and precision to run: an explicit one as given (precision auto: fp32);
    backend auto picks by device, and on the CPU by what it can do (bf16: whether OpenVINO is
    installed and finds bfloat16 instructions, None: not installed; default: asked here).

    Measured (benchmarks/results/backends.md, 2 cores): OpenVINO bf16 is 2.1x faster than ONNX
    Runtime fp32 on an Intel Xeon with AMX and 2.2x on an AMD EPYC with AVX512_BF16, its 3D
    joints within 5 cm (p95) of fp32's with the same people and ids; OpenVINO fp32 is not
    faster than ONNX Runtime everywhere (1.5x slower at imgsz 320 on the Xeon), so without
    bfloat16 the choice stays ONNX Runtime fp32, exact.

    Then, with OpenVINO installed and precision auto, OpenVINO's INT8 model of the default
    model instead, where it was made, its check against fp32 passed and it runs at least
    int8_choice.MIN_SPEEDUP times faster on this CPU (int8: an int8_choice.Int8Found; default:
    found out here, its speed measured once per machine; None: not considered)."""
    if backend != AUTO:
        if precision == AUTO:
            return Choice(backend, "fp32", "as configured")
        return Choice(backend, precision, "as configured")
    d = device.strip().lower()
    if d != "cpu":
        where = "openvino" if d.startswith("gpu") else "onnx"
        prec = "fp32" if precision == AUTO else precision
        return Choice(where, prec, f"auto: device {device} runs on the {where} backend")
    if precision not in (AUTO, "bf16"):  # int8, fp16, fp32 asked for: where they run
        if precision == "fp32":
            return Choice("onnx", "fp32", "auto: fp32 asked for; ONNX Runtime, exact")
        return Choice("onnx", precision, f"auto: {precision} runs on the onnx backend")
    if bf16 is _ASK:
        bf16 = cpu_bf16()
    if bf16:
        return _or_int8(
            Choice(
                "openvino",
                "bf16",
                "auto: this CPU has bfloat16 instructions; OpenVINO bf16 is "
                "about 2x faster than fp32, 3D joints within 5 cm",
            ),
            precision,
            int8,
        )
    if precision == "bf16":
        raise ModelError(
            "precision bf16: "
            + (
                "this CPU has no bfloat16 instructions (AVX512_BF16 or AMX); use fp32"
                if bf16 is False
                else "it needs OpenVINO: pip install 'stereopose[openvino]'"
            )
        )
    why = "no bfloat16 instructions on this CPU" if bf16 is False else "OpenVINO not installed"
    fp32 = Choice("onnx", "fp32", f"auto: {why}; ONNX Runtime fp32, exact")
    return fp32 if bf16 is None else _or_int8(fp32, precision, int8)


def _or_int8(chosen: Choice, precision: str, int8: object) -> Choice:
    """OpenVINO's INT8 model instead of the float `chosen` where auto may choose it (precision
    auto), its check against fp32 passed and it is faster on this CPU (detection.int8_choice;
    int8: an Int8Found, _ASK: found out here, None: not considered, as for a model of the
    user's own); else `chosen`, saying why not."""
    if precision != AUTO or int8 is None:
        return chosen
    from stereopose.detection.int8_choice import Int8Found, find_int8

    # weighed against OpenVINO's own run of the float model: bf16, or fp32 (about ONNX
    # Runtime's speed: results/backends.md)
    against = "OpenVINO bf16" if chosen.precision == "bf16" else "fp32"
    found = find_int8("bf16" if chosen.precision == "bf16" else "fp32") if int8 is _ASK else int8
    if not isinstance(found, Int8Found):
        raise TypeError(f"int8: an Int8Found, None or left out, not {found!r}")
    refused = found.refusal(against)
    if refused is not None:
        return Choice(chosen.backend, chosen.precision, f"{chosen.why}; INT8 not taken: {refused}")
    p95 = (found.check or {}).get("p95_px")
    return Choice(
        "openvino",
        "int8",
        f"auto: OpenVINO's INT8 model runs at {found.speedup:.2f}x {against}'s speed on this "
        f"CPU, its joints {p95} px (p95) from fp32's",
    )


def make_detector(
    backend: str = AUTO,
    model: str | Path | None = None,
    imgsz: int = 640,
    conf: float = 0.25,
    iou: float = 0.7,
    device: str = "cpu",
    threads: int | None = None,
    precision: str = AUTO,
) -> PoseDetector:
    """A pose detector. model: a local .onnx or .pt file (default: yolo11n-pose from the cache).
    backend and precision "auto": chosen here (``choose``); the detector's ``choice`` says what
    and why, logged once.

    The onnx and openvino backends given a .pt file export it to ONNX once, into the cache.
    precision "int8" (onnx only): the model quantised once into the cache (``<stem>-int8.onnx``
    beside it; a model already quantised is taken as it is); "bf16": openvino only; "fp16":
    onnx on device tensorrt only.
    """
    if backend != AUTO and backend not in BACKENDS:
        raise ModelError(
            f"unknown detector backend {backend!r}; expected auto or one of {', '.join(BACKENDS)}"
        )
    if precision != AUTO and precision not in PRECISIONS:
        raise ModelError(
            f"precision must be auto or one of {', '.join(PRECISIONS)}, got {precision!r}"
        )
    # OpenVINO's INT8 model is of the default model: a model of the user's own runs as chosen
    choice = choose(backend, precision, device, int8=_ASK if model is None else None)
    detector = _build(choice.backend, model, imgsz, conf, iou, device, threads, choice.precision)
    # the choice goes with the detector it made (the run's summary shows it)
    detector.choice = choice  # pyright: ignore[reportAttributeAccessIssue]
    logger.info("detector: %s", choice)
    return detector


def _build(
    backend: str,
    model: str | Path | None,
    imgsz: int,
    conf: float,
    iou: float,
    device: str,
    threads: int | None,
    precision: str,
) -> PoseDetector:
    """make_detector's backend, once chosen."""
    if precision not in PRECISIONS:
        raise ModelError(f"precision must be one of {', '.join(PRECISIONS)}, got {precision!r}")
    if precision == "int8" and backend not in ("onnx", "openvino"):
        raise ModelError(f"precision int8 needs the onnx or openvino backend, not {backend!r}")
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
        if precision == "int8" and backend == "openvino":
            # OpenVINO's own INT8 model (NNCF): ONNX Runtime's loses people on OpenVINO
            # (person scores about 0.3 where ONNX Runtime gives 0.9: results/backends.md)
            path = _openvino_int8(path, model is None)
        elif precision == "int8":
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


def _openvino_int8(path: Path, default: bool) -> Path:
    """OpenVINO's INT8 model of the ONNX model at `path` (an .xml given: taken as it is),
    quantised once into the cache."""
    from stereopose.detection.int8_openvino import current, quantize_int8_openvino
    from stereopose.detection.models import INT8_SUFFIX, openvino_int8_path

    if path.suffix == ".xml":
        return path
    target = openvino_int8_path() if default else models_dir() / f"{path.stem}{INT8_SUFFIX}.xml"
    return target if current(target) else quantize_int8_openvino(path, target)
