"""Calibration runs: checkerboard photos -> intrinsics, then the rig's extrinsics.

The outputs (the calibration, the report pictures) are tried before the work; if one still
cannot be written at the end, the run records it in `failures` and keeps the calibration
elsewhere (`kept`: a file in the temporary folder, or `kept_text` when even that fails), so
that minutes of board detection and adjustment are never lost.
"""

from __future__ import annotations

import logging
import tempfile
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from stereopose.calibration.board import Board
from stereopose.calibration.formats import load_calibration
from stereopose.errors import CalibrationError, StereoposeError
from stereopose.io.writing import make_folder, probe_folder, probe_output, reason
from stereopose.types import Rig

if TYPE_CHECKING:
    from stereopose.calibration.extrinsics import ExtrinsicsResult

logger = logging.getLogger(__name__)


@dataclass
class Kept:
    """What a calibration run could not write, and where its calibration went instead.

    failures: output -> why it could not be written; kept: the calibration (native TOML) saved
    in the temporary folder instead; kept_text: that TOML, when even that could not be saved.
    """

    failures: dict[str, str] = field(default_factory=dict)
    kept: Path | None = None
    kept_text: str | None = None
    outputs: list[Path] = field(default_factory=list)
    calibration: Path | None = None  # the calibration file written (None: see failures)


@dataclass
class IntrinsicsRun(Kept):
    results: dict = field(default_factory=dict)  # camera -> IntrinsicsResult
    detections: dict = field(default_factory=dict)  # camera -> [Detection]


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

    check_calibration_outputs(out, report_dir)
    run = IntrinsicsRun()
    for name, folder in _camera_folders(Path(images)):
        if on_camera is not None:
            on_camera(name)
        dets = detect_all(iter_images(folder), board)
        run.detections[name] = dets
        run.results[name] = calibrate_intrinsics(name, dets, board, k3=k3)
    rig = Rig(tuple(r.camera for r in run.results.values()))
    _save_rig(run, out, rig, {"intrinsics_only": True})
    if report_dir is not None:
        from stereopose.viz.calibration import intrinsics_png

        path = Path(report_dir) / "intrinsics.png"
        _picture(run, path, lambda: intrinsics_png(path, run.results, run.detections))
    return run


def check_calibration_outputs(out: str | Path, report_dir: str | Path | None) -> None:
    """Raise an OutputError now, before any work, if the calibration `out` (.toml, or an
    OpenCV YAML folder / .yml) or the report folder could not be written at the end."""
    from stereopose.calibration.opencv_yaml import yaml_paths

    out = Path(out)
    if out.suffix.lower() == ".toml":
        probe_output(out, "the calibration")
    else:
        probe_folder(yaml_paths(out)[0].parent, "the calibration (intri.yml, extri.yml)")
    if report_dir is not None:
        probe_folder(report_dir, "the report pictures")


def _save_rig(run: Kept, out: str | Path, rig: Rig, metadata: dict) -> None:
    """The calibration to `out` (run.outputs, run.calibration); if it cannot be written, kept
    elsewhere (see Kept) and the failure recorded."""
    from stereopose.calibration.formats import format_calibration, save_calibration
    from stereopose.calibration.opencv_yaml import write_opencv_yaml

    out = Path(out)
    text = format_calibration(rig, metadata)  # a bad rig is an error here, not a lost file
    try:
        if out.suffix.lower() == ".toml":
            make_folder(out.parent)
            save_calibration(out, rig, metadata=metadata)
            written = out
        else:
            written = write_opencv_yaml(out, rig)[0]
    except (OSError, StereoposeError) as e:  # the YAML writer's error is its cannot-write
        run.failures[str(out)] = reason(e)
        _keep(run, out, text)
        return
    run.calibration = written
    run.outputs.append(written)


def _keep(run: Kept, out: Path, text: str) -> None:
    """The calibration's TOML in a new file of the temporary folder (never one that exists);
    the text itself when that fails too."""
    try:
        fd, name = tempfile.mkstemp(prefix=f"{out.stem or 'calibration'}-", suffix=".toml")
        with open(fd, "w", encoding="utf-8", newline="\n") as f:
            f.write(text)
        run.kept = Path(name)
        logger.error("%s: cannot write the calibration; it is kept in %s", out, run.kept)
    except OSError as e:
        run.kept_text = text
        logger.error("%s: cannot write the calibration, nor keep it (%s)", out, e.strerror)


def _picture(run: Kept, path: Path, draw: Callable[[], Path]) -> None:
    """A report picture drawn to `path` (run.outputs); a failure to write it recorded."""
    try:
        make_folder(path.parent)
        run.outputs.append(draw())
    except OSError as e:
        run.failures[str(path)] = reason(e)
        logger.error("%s: cannot write the report picture: %s", path, reason(e))


@dataclass
class ExtrinsicsRun(Kept):
    result: ExtrinsicsResult | None = None
    found: dict = field(default_factory=dict)  # camera -> {position: found?}


@dataclass(frozen=True)
class ExtrinsicsOptions:
    """floor, origin_m, yaw_deg: the world frame (calibration.extrinsics.calibrate_extrinsics);
    refine_intrinsics: focal lengths and distortion refined too; intrinsics_images: the
    cameras' own board photos (as for the intrinsics), added to the adjustment as positions
    seen by one camera: with refine_intrinsics, refined from both sets at once."""

    floor: str | None = None
    origin_m: tuple[float, float] = (0.0, 0.0)
    yaw_deg: float = 0.0
    refine_intrinsics: bool = False
    intrinsics_images: str | Path | None = None


def calibrate_extrinsics_dir(
    images: str | Path,
    intrinsics: str | Path,
    board: Board,
    out: str | Path,
    options: ExtrinsicsOptions = ExtrinsicsOptions(),
    report_dir: str | Path | None = None,
    on_camera: Callable[[str], None] | None = None,
) -> ExtrinsicsRun:
    """The rig from synchronised board photos: `images` holds one sub-folder per camera with
    the same file name per board position (the position's name is the file's stem)."""
    intrinsics_images = options.intrinsics_images
    from stereopose.calibration.extrinsics import calibrate_extrinsics
    from stereopose.calibration.intrinsics import detect_all, iter_images

    rig = load_calibration(intrinsics, min_cameras=1)
    check_calibration_outputs(out, report_dir)
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
    o = options
    result = calibrate_extrinsics(
        cams, corners, board, o.floor, o.origin_m, o.yaw_deg, o.refine_intrinsics
    )
    run = ExtrinsicsRun(result=result, found=found)
    _save_rig(run, out, result.rig, {"rms_px": round(result.rms_px, 4)})
    if report_dir is not None:
        from stereopose.viz.calibration import extrinsics_png

        path = Path(report_dir) / "extrinsics.png"
        _picture(
            run,
            path,
            lambda: extrinsics_png(
                path, result.rig, board, result.board_poses, result.residuals_px
            ),
        )
    return run
