"""`calibrate intrinsics` and `calibrate extrinsics`."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

from rich.markup import escape
from rich.table import Table

from stereopose.cli.common import console, out
from stereopose.errors import IncompleteOutputError
from stereopose.extras import require

if TYPE_CHECKING:
    from stereopose.calibration.board import Board
    from stereopose.pipeline.calibrate import Kept


def _board(args: argparse.Namespace) -> Board:
    from stereopose.calibration.board import Board

    return Board.parse(args.board, args.square)


def _needs(solver: bool, pictures: bool) -> None:
    """The libraries of the calibration extra, checked before the work (a runtime install
    has neither)."""
    if solver:
        require("scipy", "calibration", "calibrate extrinsics (the bundle adjustment)")
    if pictures:
        require("matplotlib", "calibration", "the calibration pictures (--report)")


def _calibrate_intrinsics(args: argparse.Namespace) -> int:
    from stereopose.pipeline import calibrate_intrinsics_dir
    from stereopose.pipeline.paths import check_calibration_places

    _needs(solver=False, pictures=args.report is not None)
    board = _board(args)
    check_calibration_places(args.images, args.out, args.report, "intrinsics.png")
    with console.status("detecting the board") as status:
        run = calibrate_intrinsics_dir(
            args.images,
            board,
            args.out,
            k3=args.k3,
            report_dir=args.report,
            on_camera=lambda name: status.update(f"camera {name}: detecting the board"),
        )
    table = Table(title=f"Intrinsics {_where(run, args.out)}")
    for col in ("camera", "photos used", "not used", "fx", "fy", "cx", "cy", "RMS px", "coverage"):
        table.add_column(col, justify="right")
    for name, r in run.results.items():
        K = r.camera.matrix
        table.add_row(
            name,
            f"{len(r.used)}/{len(run.detections[name])}",
            str(len(r.rejected)),
            f"{K[0, 0]:.1f}",
            f"{K[1, 1]:.1f}",
            f"{K[0, 2]:.1f}",
            f"{K[1, 2]:.1f}",
            f"{r.rms_px:.3f}",
            f"{100 * r.coverage:.0f}%",
        )
    out.print(table)
    for name, r in run.results.items():
        for photo, why in r.rejected.items():
            out.print(f"{name}: {photo} not used: {why}", markup=False, highlight=False)
        for view, e in sorted(r.view_rms_px.items()):
            out.print(f"{name}: {view}: {e:.3f} px", markup=False, highlight=False)
        for w in r.warnings:
            console.print(f"[yellow]warning:[/] {escape(w)}")
    return _finish(run)


def _where(run: Kept, target: str | Path) -> str:
    return f"written to {target}" if run.calibration is not None else "(not written: see below)"


def _finish(run: Kept) -> int:
    """The pictures written, and exit code 3 (the calibration kept) if an output failed."""
    for p in run.outputs:
        if p != run.calibration:
            out.print(f"wrote {p}", markup=False, highlight=False)
    if not run.failures:
        return 0
    note = ""
    if run.kept is not None:
        note = f"the calibration is kept in {run.kept}"
    elif run.kept_text is not None:  # on standard output, where it can still be saved from
        out.print(run.kept_text, markup=False, highlight=False)
        note = "the calibration could not be kept in a file: it is printed above"
    raise IncompleteOutputError(run.failures, note=note)


def _calibrate_extrinsics(args: argparse.Namespace) -> int:
    from stereopose.pipeline import calibrate_extrinsics_dir
    from stereopose.pipeline.calibrate import ExtrinsicsOptions
    from stereopose.pipeline.paths import check_calibration_places

    _needs(solver=True, pictures=args.report is not None)
    board = _board(args)
    check_calibration_places(
        args.images,
        args.out,
        args.report,
        "extrinsics.png",
        args.intrinsics,
        args.intrinsics_images,
    )
    with console.status("detecting the board") as status:
        run = calibrate_extrinsics_dir(
            args.images,
            args.intrinsics,
            board,
            args.out,
            ExtrinsicsOptions(
                args.floor,
                tuple(args.origin),
                args.yaw,
                args.refine_intrinsics,
                args.intrinsics_images,
            ),
            report_dir=args.report,
            on_camera=lambda name: status.update(f"camera {name}: detecting the board"),
        )
    r = run.result
    assert r is not None  # the rig calibrated (or a CalibrationError)
    table = Table(title=f"Rig {_where(run, args.out)}: RMS {r.rms_px:.3f} px")
    for col in ("camera", "board positions seen", "RMS px", "x m", "y m", "z m"):
        table.add_column(col, justify="right")
    for cam in r.rig:
        seen = sum(run.found[cam.name].values())
        x, y, z = cam.center
        table.add_row(
            cam.name,
            f"{seen}/{len(run.found[cam.name])}",
            f"{r.camera_rms_px[cam.name]:.3f}",
            f"{x:.3f}",
            f"{y:.3f}",
            f"{z:.3f}",
        )
    out.print(table)
    for view, e in sorted(r.view_rms_px.items()):
        out.print(f"position {view}: {e:.3f} px", markup=False, highlight=False)
    for w in r.warnings:
        console.print(f"[yellow]warning:[/] {escape(w)}")
    out.print(f"bundle adjustment and pose graph: {r.seconds:.2f} s")
    return _finish(run)
