"""Calibration runs: checkerboard photos -> intrinsics, then the rig's extrinsics."""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from stereopose.calibration.board import Board
from stereopose.calibration.formats import load_calibration
from stereopose.errors import CalibrationError
from stereopose.types import Rig

logger = logging.getLogger(__name__)


@dataclass
class IntrinsicsRun:
    results: dict  # camera -> IntrinsicsResult
    detections: dict  # camera -> [Detection]
    outputs: list[Path] = field(default_factory=list)


def _camera_folders(images: Path) -> list[tuple[str, Path]]:
    """(camera name, folder or video) of a folder holding one camera's photos, or one
    sub-folder (or video) per camera."""
    from stereopose.calibration.intrinsics import IMAGE_SUFFIXES, VIDEO_SUFFIXES, camera_name

    if images.is_file():
        return [(camera_name(images.stem), images)]
    if not images.is_dir():
        raise CalibrationError(f"{images}: not a folder of photos or a video file")
    subs = sorted(
        p
        for p in images.iterdir()
        if p.is_dir() or (p.is_file() and p.suffix.lower() in VIDEO_SUFFIXES)
    )
    photos = [p for p in images.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES]
    if photos or not subs:
        return [(camera_name(images.name), images)]
    return [(camera_name(p.stem if p.is_file() else p.name), p) for p in subs]


def calibrate_intrinsics_dir(
    images: str | Path,
    board: Board,
    out: str | Path,
    k3: bool = False,
    report_dir: str | Path | None = None,
    on_camera: Callable[[str], None] | None = None,
) -> IntrinsicsRun:
    """Intrinsics of every camera found under `images`, written to `out` (.toml, or an
    OpenCV YAML folder / .yml); a PNG report in report_dir."""
    from stereopose.calibration.intrinsics import calibrate_intrinsics, detect_all, iter_images

    run = IntrinsicsRun({}, {})
    for name, folder in _camera_folders(Path(images)):
        if on_camera is not None:
            on_camera(name)
        dets = detect_all(iter_images(folder), board)
        run.detections[name] = dets
        run.results[name] = calibrate_intrinsics(name, dets, board, k3=k3)
    rig = Rig(tuple(r.camera for r in run.results.values()))
    run.outputs.append(_save_rig(out, rig, {"intrinsics_only": True}))
    if report_dir is not None:
        from stereopose.viz.calibration import intrinsics_png

        Path(report_dir).mkdir(parents=True, exist_ok=True)
        run.outputs.append(
            intrinsics_png(Path(report_dir) / "intrinsics.png", run.results, run.detections)
        )
    return run


def _save_rig(out: str | Path, rig: Rig, metadata: dict) -> Path:
    from stereopose.calibration.formats import save_calibration
    from stereopose.calibration.opencv_yaml import write_opencv_yaml

    out = Path(out)
    if out.suffix.lower() == ".toml":
        out.parent.mkdir(parents=True, exist_ok=True)
        save_calibration(out, rig, metadata=metadata)
        return out
    return write_opencv_yaml(out, rig)[0]


@dataclass
class ExtrinsicsRun:
    result: object  # ExtrinsicsResult
    found: dict  # camera -> {position: found?}
    outputs: list[Path] = field(default_factory=list)


def calibrate_extrinsics_dir(
    images: str | Path,
    intrinsics: str | Path,
    board: Board,
    out: str | Path,
    floor: str | None = None,
    origin_m: tuple[float, float] = (0.0, 0.0),
    yaw_deg: float = 0.0,
    refine_intrinsics: bool = False,
    report_dir: str | Path | None = None,
    on_camera: Callable[[str], None] | None = None,
    intrinsics_images: str | Path | None = None,
) -> ExtrinsicsRun:
    """The rig from synchronised board photos: `images` holds one sub-folder per camera with
    the same file name per board position (the position's name is the file's stem).

    intrinsics_images: the cameras' own board photos (as for the intrinsics), added to the
    adjustment as positions seen by one camera: with refine_intrinsics, focal lengths and
    distortion are then refined from both sets at once."""
    from stereopose.calibration.extrinsics import calibrate_extrinsics
    from stereopose.calibration.intrinsics import detect_all, iter_images

    rig = load_calibration(intrinsics, min_cameras=1)
    cams = {c.name: c for c in rig}
    corners: dict[str, dict[str, np.ndarray]] = {}
    found: dict[str, dict[str, bool]] = {}
    folders = _camera_folders(Path(images))
    if len(folders) < 2:
        raise CalibrationError(f"{images}: needs one sub-folder of photos per camera (>= 2)")
    for name, folder in folders:
        if name not in cams:
            raise CalibrationError(
                f"{folder}: camera {name!r} has no intrinsics in {intrinsics} "
                f"(cameras there: {', '.join(cams)})"
            )
        if on_camera is not None:
            on_camera(name)
        dets = detect_all(iter_images(folder), board)
        for d in dets:
            if d.image_size is not None and tuple(d.image_size) != tuple(
                int(v) for v in cams[name].size
            ):
                raise CalibrationError(
                    f"{folder}/{d.name}: image size {d.image_size} differs from camera "
                    f"{name}'s {tuple(int(v) for v in cams[name].size)} in {intrinsics}"
                )
        corners[name] = {Path(d.name).stem: d.corners.points for d in dets if d.corners}
        found[name] = {Path(d.name).stem: d.corners is not None for d in dets}
    if intrinsics_images is not None:
        for name, folder in _camera_folders(Path(intrinsics_images)):
            if name not in corners:
                continue
            if on_camera is not None:
                on_camera(f"{name} (intrinsics photos)")
            for d in detect_all(iter_images(folder), board):
                if d.corners is not None:
                    corners[name][f"{name}:{Path(d.name).stem}"] = d.corners.points
    result = calibrate_extrinsics(cams, corners, board, floor, origin_m, yaw_deg, refine_intrinsics)
    run = ExtrinsicsRun(result, found)
    run.outputs.append(_save_rig(out, result.rig, {"rms_px": round(result.rms_px, 4)}))
    if report_dir is not None:
        from stereopose.viz.calibration import extrinsics_png

        Path(report_dir).mkdir(parents=True, exist_ok=True)
        run.outputs.append(
            extrinsics_png(
                Path(report_dir) / "extrinsics.png",
                result.rig,
                board,
                result.board_poses,
                result.residuals_px,
            )
        )
    return run
