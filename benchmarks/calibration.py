"""Calibration: real checkerboard photos against Qualisys, a synthetic rig, and the time of the
bundle adjustment.

- Real photos (pose2sim demo, 4 cameras x 7 photos, 4x7 inner corners, 60 mm): photos with the
  board found, and fx against an independent Qualisys calibration of the same cameras.
- Synthetic rig of 6 cameras and 20 board positions (the 15 x 11 x 50 mm board, corners with
  0.2 px noise; intrinsics from 15 close-up photos per camera, adjusted with the rig): fx,
  camera centre and rotation errors in the world frame of the floor board.
- Time of the pose graph and bundle adjustment for 8 cameras x 20 positions.
Results are written to benchmarks/results/calibration.{md,json}.

usage: python benchmarks/calibration.py [--no-real]
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse
import datetime
import sys
import time
from pathlib import Path

import numpy as np

from stereopose.calibration.board import Board
from stereopose.calibration.corners import Corners
from stereopose.calibration.extrinsics import calibrate_extrinsics
from stereopose.calibration.intrinsics import (
    Detection,
    calibrate_intrinsics,
    camera_name,
    detect_all,
    iter_images,
)
from stereopose.sim.calibration import board_scene, close_views, corner_observations
from stereopose.sim.scene import make_rig

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from common import machine, save

QUALISYS_FX = {"cam01": 1681.2, "cam02": 1673.7, "cam03": 1681.6, "cam04": 1675.2}
BOARD = Board(14, 10, 0.05)


def real() -> list[dict]:
    from stereopose.io.pose2sim_data import pose2sim_demo_dir

    folder = pose2sim_demo_dir() / "Demo_SinglePerson" / "calibration" / "intrinsics"
    board = Board(4, 7, 0.06)
    rows = []
    for sub in sorted(folder.iterdir()):
        name = camera_name(sub.name)
        t0 = time.perf_counter()
        dets = detect_all(iter_images(sub), board)
        r = calibrate_intrinsics(name, dets, board)
        fx = float(r.camera.matrix[0, 0])
        rows.append(
            {
                "camera": name,
                "photos": len(dets),
                "found": sum(d.corners is not None for d in dets),
                "used": len(r.used),
                "fx": fx,
                "qualisys_fx": QUALISYS_FX[name],
                "fx_error": fx / QUALISYS_FX[name] - 1.0,
                "rms_px": r.rms_px,
                "seconds": time.perf_counter() - t0,
            }
        )
        x = rows[-1]
        print(
            f"real {name}: board in {x['found']}/{x['photos']} photos, fx {fx:.1f} vs Qualisys "
            f"{x['qualisys_fx']} ({100 * x['fx_error']:+.2f}%), RMS {x['rms_px']:.3f} px",
            flush=True,
        )
    return rows


def synthetic(seeds: int = 5) -> dict:
    fx_err, centre, rot = [], [], []
    for seed in range(seeds):
        rig = make_rig(6, np.random.default_rng([seed, 3]))
        rng = np.random.default_rng([seed, 4])
        scene = board_scene(rig, BOARD, 20, rng)
        obs = corner_observations(rig, scene, 0.2, rng)
        cams = {}
        for cam in rig:
            close = close_views(cam, BOARD, 15, 0.2, rng)
            dets = [
                Detection(v, (1920, 1080), Corners(p, "synthetic", 0.0, 40.0))
                for v, p in close.items()
            ]
            cams[cam.name] = calibrate_intrinsics(cam.name, dets, BOARD).camera
            for v, p in close.items():  # adjusted together with the rig
                obs[cam.name][f"{cam.name}:{v}"] = p
        res = calibrate_extrinsics(cams, obs, BOARD, floor=scene.floor, refine_intrinsics=True)
        for cam in rig:
            got = res.rig[cam.name]
            fx_err.append(abs(got.matrix[0, 0] / cam.matrix[0, 0] - 1.0))
            centre.append(float(np.linalg.norm(got.center + scene.origin - cam.center)))
            c = (np.trace(got.R.T @ cam.R) - 1) / 2
            rot.append(float(np.degrees(np.arccos(np.clip(c, -1, 1)))))
    row = {
        "rigs": seeds,
        "fx_error_max": max(fx_err),
        "centre_error_max_m": max(centre),
        "centre_error_mean_m": float(np.mean(centre)),
        "rotation_error_max_deg": max(rot),
        "rotation_error_mean_deg": float(np.mean(rot)),
    }
    print(
        f"synthetic rig 6 x 20, {seeds} rigs: fx within {100 * row['fx_error_max']:.2f}%, "
        f"centres within {1000 * row['centre_error_max_m']:.1f} mm (mean "
        f"{1000 * row['centre_error_mean_m']:.1f}), rotations within "
        f"{row['rotation_error_max_deg']:.3f} deg",
        flush=True,
    )
    return row


def timing(runs: int = 3) -> dict:
    rig = make_rig(8, np.random.default_rng(8))
    rng = np.random.default_rng(9)
    scene = board_scene(rig, BOARD, 20, rng)
    obs = corner_observations(rig, scene, 0.2, rng)
    cams = {c.name: c for c in rig}
    views = sum(len(v) for v in obs.values())
    times, times_refine = [], []
    for _ in range(runs):
        times.append(calibrate_extrinsics(cams, obs, BOARD, floor=scene.floor).seconds)
        times_refine.append(
            calibrate_extrinsics(
                cams, obs, BOARD, floor=scene.floor, refine_intrinsics=True
            ).seconds
        )
    row = {
        "cameras": 8,
        "positions": 20,
        "views": views,
        "corners": views * BOARD.count,
        "seconds": min(times),
        "seconds_refine_intrinsics": min(times_refine),
    }
    print(
        f"bundle adjustment 8 cameras x 20 positions ({views} views, {row['corners']} corners): "
        f"{row['seconds']:.2f} s, {row['seconds_refine_intrinsics']:.2f} s refining intrinsics",
        flush=True,
    )
    return row


def write(results: dict) -> None:
    s, t = results["synthetic"], results["timing"]
    md = [
        "# Calibration: accuracy and time",
        "",
        f"Measured {results['date']} on {results['machine']} by `benchmarks/calibration.py`.",
        "",
    ]
    if results["real"]:
        md += [
            "## Real checkerboard photos (pose2sim demo)",
            "",
            "4x7 inner corners, 60 mm squares, 7 portrait photos (1088 x 1920) per camera; fx "
            "against an independent Qualisys calibration of the same cameras.",
            "",
            "| camera | board found | photos used | fx px | Qualisys fx px | error | RMS px |",
            "|---|---:|---:|---:|---:|---:|---:|",
        ]
        for r in results["real"]:
            md.append(
                f"| {r['camera']} | {r['found']}/{r['photos']} | {r['used']} | {r['fx']:.1f} | "
                f"{r['qualisys_fx']} | {100 * r['fx_error']:+.2f}% | {r['rms_px']:.3f} |"
            )
        md.append("")
    md += [
        "## Synthetic rig",
        "",
        f"{s['rigs']} simulated rigs of 6 ceiling cameras (1920 x 1080, focal 750-1100 px, "
        "barrel distortion), the 15 x 11 board of 50 mm shown at 20 positions (one on the "
        "floor), corners with 0.2 px noise; intrinsics from 15 close-up photos per camera "
        "(Zhang), then one bundle adjustment of everything, those photos included, intrinsics "
        "refined (`--intrinsics-images` with `--refine-intrinsics`). Errors in the floor "
        "board's world frame.",
        "",
        "| fx error, max | centre error, max | centre error, mean | rotation error, max "
        "| rotation error, mean |",
        "|---:|---:|---:|---:|---:|",
        f"| {100 * s['fx_error_max']:.2f}% | {1000 * s['centre_error_max_m']:.1f} mm | "
        f"{1000 * s['centre_error_mean_m']:.1f} mm | {s['rotation_error_max_deg']:.3f} deg | "
        f"{s['rotation_error_mean_deg']:.3f} deg |",
        "",
        "## Bundle adjustment time",
        "",
        "| cameras x positions | views | corners | pose graph + adjustment s "
        "| with intrinsics refined s |",
        "|---|---:|---:|---:|---:|",
        f"| {t['cameras']} x {t['positions']} | {t['views']} | {t['corners']} | "
        f"{t['seconds']:.2f} | {t['seconds_refine_intrinsics']:.2f} |",
    ]
    save("calibration", results, md)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--no-real", action="store_true", help="skip the real photos")
    args = ap.parse_args()
    results = {
        "date": datetime.date.today().isoformat(),
        "machine": machine(),
        "timing": timing(),
        "synthetic": synthetic(),
        "real": [] if args.no_real else real(),
    }
    write(results)


if __name__ == "__main__":
    main()
