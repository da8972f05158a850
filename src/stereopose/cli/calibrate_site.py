"""`calibrate points`, `calibrate people` and `calibrate refine`: a rig without a board."""

from __future__ import annotations

import argparse
import json
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from rich.markup import escape
from rich.table import Table

from stereopose.cli.common import console, out
from stereopose.errors import CalibrationError, IncompleteOutputError, StereoposeError
from stereopose.extras import require

if TYPE_CHECKING:
    from stereopose.calibration.people import Frames
    from stereopose.calibration.surveyed import Survey
    from stereopose.types import Rig

MAX_FRAMES = 600  # frames sampled evenly from the recording at most
MIN_SHARED = 0.5  # a camera's frames that other cameras have too, at least


def _intrinsics(path: Path) -> Rig:
    from stereopose.calibration.formats import load_calibration

    return load_calibration(path, min_cameras=1)


def _frames(pose_dir: Path, rig: Rig, max_frames: int) -> list:
    """Evenly sampled synchronised frames of the cameras' keypoint folders; CalibrationError
    for folders that share too few frame numbers (not synchronised) or hold nobody."""
    from stereopose.detection.openpose import read_pose_dir

    if not 10 <= max_frames <= 100_000:
        raise StereoposeError(f"--max-frames: {max_frames} is not between 10 and 100000")
    seq = read_pose_dir(pose_dir, rig.names)
    numbers = {c: set(seq.files(c)) for c in seq.cameras}
    for c, mine in numbers.items():
        others = (
            set().union(*(v for k, v in numbers.items() if k != c)) if len(numbers) > 1 else set()
        )
        if mine and len(mine & others) < MIN_SHARED * len(mine):
            span = lambda s: f"{min(s)}..{max(s)}" if s else "none"  # noqa: E731
            raise CalibrationError(
                f"{pose_dir}: camera {c}'s frames ({span(mine)}) are not the other cameras' "
                f"({span(others)}): the folders are not synchronised (the same frame number "
                "must be the same instant in every camera)"
            )
    chosen = seq.frames
    if len(chosen) > max_frames:
        chosen = [chosen[int(i)] for i in np.linspace(0, len(chosen) - 1, max_frames)]
    frames = [(n, seq.frame(n)) for n in chosen]
    if not any(len(p.keypoints) for _, people in frames for p in people.values()):
        raise CalibrationError(f"{pose_dir}: no person detected in {len(frames)} frame(s)")
    return frames


def _save(path: Path, rig: Rig, metadata: dict) -> None:
    from stereopose.calibration.formats import save_calibration

    try:
        save_calibration(path, rig, metadata)
    except OSError as e:
        raise StereoposeError(f"{path}: cannot write the calibration: {e.strerror}") from None


def _report(folder: Path | None, name: str, doc: dict) -> None:
    if folder is None:
        return
    try:
        folder.mkdir(parents=True, exist_ok=True)
        path = folder / name
        path.write_text(json.dumps(doc, indent=1, default=float) + "\n", encoding="utf-8")
    except OSError as e:
        raise StereoposeError(f"{folder}: cannot write the report: {e.strerror}") from None
    out.print(f"wrote {path}", markup=False, highlight=False)


def _rig_table(title: str, rig: Rig, rms: dict, extra: dict[str, dict] | None = None) -> None:
    extra = extra or {}
    table = Table(title=title)
    cols = ["camera", "RMS px", *extra, "x m", "y m", "z m"]
    for col in cols:
        table.add_column(col, justify="right")
    for cam in rig:
        x, y, z = cam.center
        table.add_row(
            cam.name,
            f"{rms.get(cam.name, float('nan')):.2f}",
            *(str(v.get(cam.name, "")) for v in extra.values()),
            f"{x:.3f}",
            f"{y:.3f}",
            f"{z:.3f}",
        )
    out.print(table)


def _calibrate_points(args: argparse.Namespace) -> int:
    from stereopose.calibration.surveyed import calibrate_points, read_survey

    require("scipy", "calibration", "calibrate points (the adjustment)")
    survey = read_survey(args.points)
    r = calibrate_points(_intrinsics(args.intrinsics), survey)
    for cam, point, px in r.left_out:
        out.print(
            f"left out: camera {cam}, point {point}: {px:.1f} px from where the others put it",
            markup=False,
            highlight=False,
        )
    _save(args.out, r.rig, {"method": "surveyed points", "points": str(args.points)})
    _rig_table(f"Rig from surveyed points, written to {args.out}", r.rig, r.camera_rms_px)
    for w in r.warnings:
        console.print(f"[yellow]warning:[/] {escape(w)}")
    _report(
        args.report,
        "points.json",
        {
            "camera_rms_px": r.camera_rms_px,
            "residuals_px": r.residuals_px,
            "left_out": [{"camera": c, "point": p, "px": e} for c, p, e in r.left_out],
            "points": {p: v.tolist() for p, v in r.points.items()},
            "warnings": r.warnings,
            "unplaced": r.unplaced,
        },
    )
    if r.unplaced:  # finished, the others written: exit 3, each camera named with the way on
        raise IncompleteOutputError(
            {f"camera {c}": why for c, why in r.unplaced.items()},
            note=f"{len(r.rig)} camera(s) placed and written to {args.out}; "
            f"{len(r.unplaced)} not placed",
        )
    return 0


@dataclass(frozen=True)
class _Scale:
    """The rig's scale: one of a distance between cameras, the walkers' height or a survey."""

    distance: tuple[str, str, float] | None = None
    height_m: float | None = None
    survey: Survey | None = None


def _scale(args: argparse.Namespace) -> _Scale:
    if args.distance is not None:
        a, b, metres = args.distance
        try:
            d = float(metres)
        except ValueError:
            raise StereoposeError(f"--distance: {metres!r} is not a number of metres") from None
        if not 0 < d < 1e4:
            raise StereoposeError(f"--distance: {metres} m is not a distance between cameras")
        return _Scale(distance=(a, b, d))
    if args.height is not None:
        if not 1.0 <= args.height <= 2.3:
            raise StereoposeError(f"--height: {args.height} m is not a person's height")
        return _Scale(height_m=args.height)
    from stereopose.calibration.surveyed import read_survey

    return _Scale(survey=read_survey(args.points))


def _recordings(dirs: list[Path], rig: Rig, max_frames: int) -> list[list]:
    """Each folder's frames (its own frame numbers); the same folder twice is an error."""
    seen: set[Path] = set()
    for d in dirs:
        key = d.resolve()
        if key in seen:
            raise StereoposeError(f"--pose: {d} is given twice")
        seen.add(key)
    return [_frames(d, rig, max_frames) for d in dirs]


def _calibrate_people(args: argparse.Namespace) -> int:
    from stereopose.calibration.people import calibrate_people

    require("scipy", "calibration", "calibrate people (the bundle adjustment)")
    scale = _scale(args)
    if not 0.0 <= args.ankle_height <= 0.3:
        raise StereoposeError(f"--ankle-height: {args.ankle_height} m is not an ankle's height")
    intrinsics = _intrinsics(args.intrinsics)
    recordings = _recordings(args.pose, intrinsics, args.max_frames)
    n_frames = sum(len(r) for r in recordings)
    where = f"{n_frames} frames" + (f" of {len(recordings)} recordings" * (len(recordings) > 1))
    with console.status(f"calibrating {len(intrinsics)} cameras from {where}"):
        r = calibrate_people(
            recordings,
            intrinsics,
            distance=scale.distance,
            height_m=scale.height_m,
            survey=scale.survey,
            ankle_m=args.ankle_height,
            held_out=args.held_out,
        )
    pose = ", ".join(str(d) for d in args.pose)
    _save(args.out, r.rig, {"method": "people", "pose": pose, "scale": r.scale_from})
    fit = {"fit px": {k: f"{v:.1f}" for k, v in r.fit_px.items()}}
    for i, h in r.held_out_px.items():
        fit[f"held out {i + 1} px"] = {k: f"{v:.1f}" for k, v in h.items()}
    _rig_table(
        f"Rig from people, written to {args.out} (scale: {r.scale_from})",
        r.rig,
        r.camera_rms_px,
        {
            "joints": r.joints_used,
            "point-like": r.point_like,
            "frames": r.frames_used,
            "view covered": {k: f"{100 * v:.0f}%" for k, v in r.coverage.items()},
            **fit,
        },
    )
    if r.held_out_px:
        out.print(
            "fit px: median reprojection error on the recordings calibrated on; held out N: "
            "on recording N (--pose order) by the rig from the others ("
            + ", ".join(f"{i + 1}: {v:.1f} px" for i, v in r.held_out_all_px.items())
            + " over all cameras)",
            markup=False,
            highlight=False,
        )
    for a in r.advice:
        console.print(f"[yellow]coverage:[/] {escape(a)}")
    for w in r.warnings:
        console.print(f"[yellow]warning:[/] {escape(w)}")
    if len(recordings) == 1 and args.held_out:
        out.print(
            "one recording: no held-out check; record another walk with the same cameras and "
            "give both folders to --pose to see each camera's fit on people it was not "
            "calibrated on",
            markup=False,
            highlight=False,
        )
    out.print(f"{where} in {r.seconds:.1f} s", markup=False, highlight=False)
    _report(
        args.report,
        "people.json",
        {
            "scale": r.scale_from,
            "recordings": [str(d) for d in args.pose],
            "camera_rms_px": r.camera_rms_px,
            "fit_px": r.fit_px,
            "held_out_px": {str(args.pose[i]): h for i, h in r.held_out_px.items()},
            "held_out_all_px": {str(args.pose[i]): v for i, v in r.held_out_all_px.items()},
            "point_like_joints": r.point_like,
            "joints_used": r.joints_used,
            "frames_used": r.frames_used,
            "coverage": r.coverage,
            "advice": r.advice,
            "warnings": r.warnings,
            "seconds": r.seconds,
        },
    )
    return 0


def _calibrate_refine(args: argparse.Namespace) -> int:
    from stereopose.calibration.formats import load_calibration
    from stereopose.calibration.refine import refine_rig

    rig = load_calibration(args.calib)
    # recordings pooled: each frame stands alone here, so their frames simply follow
    frames = [f for r in _recordings(args.pose, rig, args.max_frames) for f in r]
    if args.cameras is not None:
        names = [c.strip() for c in args.cameras.split(",") if c.strip()]
        if not names:
            raise StereoposeError("--cameras: name the cameras to place again (cam03,cam05)")
    else:  # the cameras the others disagree with
        names = _disagreeing(rig, frames)
        if not names:
            out.print("every camera agrees with the others: nothing to place again")
            _save(args.out, rig, {"method": "refined from people", "refined": ""})
            return 0
    new, done = refine_rig(rig, names, frames)
    _save(args.out, new, {"method": "refined from people", "refined": ",".join(names)})
    _rig_table(
        f"Rig with {', '.join(names)} placed again, written to {args.out}",
        new,
        {n: r.rms_px for n, r in done.items()},
        {
            "joints": {n: r.joints for n, r in done.items()},
            "turned deg": {n: f"{r.turned_deg:.3f}" for n, r in done.items()},
            "moved m": {n: f"{r.moved_m:.3f}" for n, r in done.items()},
        },
    )
    for n, r in done.items():
        if r.coverage < 0.5:
            console.print(
                f"[yellow]coverage:[/] camera {escape(n)}: the people covered "
                f"{100 * r.coverage:.0f}% of its view; walk across it for a better pose"
            )
    return 0


def _disagreeing(
    rig: Rig, frames: Frames, turned_deg: float = 0.1, moved_m: float = 0.05
) -> list[str]:
    """The cameras that, placed from the others' people, turn or move beyond the bounds."""
    from stereopose.calibration.refine import joints_of_others, refine_camera

    found = []
    for name in rig.names:
        try:
            r = refine_camera(rig[name], joints_of_others(rig, name, frames))
        except CalibrationError as e:
            console.print(f"[yellow]warning:[/] {escape(str(e))}")
            continue
        if r.turned_deg > turned_deg or r.moved_m > moved_m:
            out.print(
                f"camera {name}: the others place it {r.turned_deg:.2f} deg and "
                f"{r.moved_m:.2f} m away",
                markup=False,
                highlight=False,
            )
            found.append(name)
    return found
