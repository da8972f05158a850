"""Accuracy and speed of the 3D stage (association + triangulation) for each mode.

Simulated scenes of three difficulties (ground truth from stereopose.sim) give MPJPE, PCP, person
recall and false people; a 6-camera x 5-person scene gives frames/s on one core (file reading
excluded); the shared real detections give the reprojection error. Results are written to
benchmarks/results/reconstruction.{md,json}.

usage: python benchmarks/reconstruction.py [--frames 300] [--seeds 5]
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"  # one core, before numpy loads

import sys
import time
from pathlib import Path

import numpy as np

from stereopose.calibration.formats import load_calibration
from stereopose.config import (
    MODES,
    AssociationConfig,
    Config,
    ReconstructionConfig,
    TrackingConfig,
    TriangulationConfig,
)
from stereopose.detection.openpose import read_pose_dir
from stereopose.geometry.camera import project
from stereopose.pipeline.stage3d import Stage3D
from stereopose.sim import evaluate, simulate

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from common import save, start

SHARED = HERE.parent.parent / "shared" / "data" / "pose2sim-demo-yolo11n"


# the robust mode is measured twice: as run (the previous frames' people seed each frame)
# and with every frame on its own
ALONE = "robust, frames alone"
VARIANTS = (*MODES, ALONE)


def config(mode: str) -> ReconstructionConfig:
    if mode == ALONE:
        return ReconstructionConfig(
            association=AssociationConfig(continuity_frames=0),
            triangulation=TriangulationConfig(mode="robust"),
        )
    return ReconstructionConfig(triangulation=TriangulationConfig(mode=mode))


def per_frame(rig, mode: str):
    """The per-frame 3D stage (no tracking: the memory of recent people) of one mode."""
    cfg = Config(reconstruction=config(mode), tracking=TrackingConfig(memory="recent"))
    stage = Stage3D(rig, cfg)
    stage.load()  # the compiled loops, loaded once before the first frame
    return stage.step


def run_scene(scene, mode: str, repeat: int = 1) -> tuple[list, list[tuple[float, float]]]:
    """Predictions for every frame, and frames/s of each of `repeat` runs, by the wall clock
    and by the process's CPU time."""
    rates = []
    for _ in range(repeat):
        rec = per_frame(scene.rig, mode)
        t0, c0 = time.perf_counter(), time.process_time()
        preds = [rec(t, dets) for t, dets in enumerate(scene.detections)]
        n = len(scene.detections)
        rates.append((n / (time.perf_counter() - t0), n / (time.process_time() - c0)))
    return preds, rates


def accuracy(frames: int, seeds: int) -> list[dict]:
    rows = []
    for difficulty in ("easy", "mid", "hard"):
        scenes = [simulate(num_frames=frames, seed=s, difficulty=difficulty) for s in range(seeds)]
        for mode in VARIANTS:
            metrics = []
            for scene in scenes:
                preds, _ = run_scene(scene, mode)
                metrics.append(evaluate(preds, scene).as_dict())
            row = {
                "difficulty": difficulty,
                "mode": mode,
                "cameras": len(scenes[0].rig),
                "people": int(scenes[0].truth.shape[1]),
            }
            for key in ("mpjpe_mm", "pcp", "pcp_seen", "person_recall", "false_people_per_frame"):
                row[key] = float(np.mean([m[key] for m in metrics]))
            rows.append(row)
            print(
                f"{difficulty:5s} {mode:20s} MPJPE {row['mpjpe_mm']:6.1f} mm  "
                f"PCP {100 * row['pcp']:5.1f}% (seen {100 * row['pcp_seen']:5.1f}%)  "
                f"recall {100 * row['person_recall']:5.1f}%  "
                f"false {row['false_people_per_frame']:.3f}/frame",
                flush=True,
            )
    return rows


def speed(frames: int) -> list[dict]:
    scene = simulate(num_cameras=6, num_people=5, num_frames=frames, seed=7, difficulty="mid")
    rows = []
    for mode in VARIANTS:
        _, rates = run_scene(scene, mode, repeat=9)
        wall, cpu = np.array(rates).T
        fps, median = float(wall.max()), float(np.median(wall))
        rows.append(
            {
                "mode": mode,
                "cameras": 6,
                "people": 5,
                "fps": fps,
                "median_fps": median,
                "cpu_fps": float(cpu.max()),
                "cpu_median_fps": float(np.median(cpu)),
            }
        )
        print(
            f"speed {mode:20s} {fps:5.0f} frames/s best, {median:5.0f} median of 9 runs, by CPU "
            f"time {cpu.max():5.0f} best, {np.median(cpu):5.0f} median (6 cameras x 5 people)",
            flush=True,
        )
    return rows


def all_view_errors(rig, frames, outs) -> np.ndarray:
    """Pixel error of every reconstructed joint in every view of its person where the 2D joint
    has confidence > 0.5, whether or not that view was used (labels as detected)."""
    errors = []
    for (_, dets), o in zip(frames, outs, strict=True):
        for p in range(len(o)):
            for c, cam in enumerate(rig):
                k = o.detections[p, c]
                if k < 0:
                    continue
                kp = dets[cam.name].keypoints[k]
                e = np.linalg.norm(project(o.joints[p], cam) - kp[:, :2], axis=-1)
                errors.extend(e[(kp[:, 2] > 0.5) & np.isfinite(e)].tolist())
    return np.array(errors)


def real() -> list[dict]:
    if not SHARED.is_dir():
        print(f"shared real detections not found at {SHARED}; skipped", file=sys.stderr)
        return []
    rig = load_calibration(SHARED / "calib.toml")
    frames = list(read_pose_dir(SHARED / "pose", rig.names))
    rows = []
    for mode in VARIANTS:
        rec = per_frame(rig, mode)
        outs = [rec(f, d) for f, d in frames]
        used = np.concatenate([o.reprojection_px[o.conf > 0.5] for o in outs])
        every = all_view_errors(rig, frames, outs)
        rows.append(
            {
                "mode": mode,
                "frames": len(outs),
                "frames_with_2_people": int(sum(len(o) >= 2 for o in outs)),
                "median_reprojection_px": float(np.nanmedian(used)),
                "median_reprojection_all_views_px": float(np.median(every)),
                "mean_views": float(np.mean(np.concatenate([o.views[o.conf > 0.5] for o in outs]))),
            }
        )
        r = rows[-1]
        print(
            f"real  {mode:20s} >=2 people in {r['frames_with_2_people']}/{r['frames']} frames, "
            f"median reprojection {r['median_reprojection_px']:.2f} px",
            flush=True,
        )
    return rows


def write(results: dict) -> None:
    md = [
        "# 3D stage: accuracy and speed",
        "",
        f"Measured {results['date']} on {results['machine']} by `benchmarks/reconstruction.py "
        f"--frames {results['frames']} --seeds {results['seeds']}`.",
        "",
        "## Simulated substations (ground truth)",
        "",
        "MPJPE over matched people; PCP over the 10 body limbs of every true person the detector "
        "reported in >= 2 cameras (a missed person or joint counts as wrong); PCP seen: the same "
        "over the limbs whose two joints the detector reported in >= 2 cameras, the limbs any "
        "triangulation can reach; person recall; false people per frame. Frames are "
        "reconstructed in order, one call each, without tracking: `robust` (the default) lets "
        "the people of the last 3 frames seed each frame (their grouping and left/right labels "
        "carry over unless the views disagree); `robust, frames alone` is the same mode with "
        "every frame on its own (`continuity_frames = 0`).",
        "",
        "| difficulty | cameras x people | mode | MPJPE mm | PCP % | PCP seen % | recall % "
        "| false/frame |",
        "|---|---|---|---:|---:|---:|---:|---:|",
    ]
    for r in results["accuracy"]:
        md.append(
            f"| {r['difficulty']} | {r['cameras']} x {r['people']} | {r['mode']} | "
            f"{r['mpjpe_mm']:.1f} | {100 * r['pcp']:.2f} | {100 * r['pcp_seen']:.2f} | "
            f"{100 * r['person_recall']:.2f} | "
            f"{r['false_people_per_frame']:.3f} |"
        )
    md += [
        "",
        "## Speed of the 3D stage (one core, file reading excluded)",
        "",
        f"9 runs over the same {results['frames']} frames of a mid scene with 6 cameras and 5 "
        "people; this machine's speed varies between runs, so both the best and the median run "
        "are given, by the wall clock and by the process's CPU time (they differ when the "
        "process waits for the CPU). The compiled loops are loaded before each run, as a run "
        "does before its first frame (their one-time loading is not in these figures).",
        "",
        "| mode | cameras x people | frames/s, best | frames/s, median | by CPU time, best "
        "| median |",
        "|---|---|---:|---:|---:|---:|",
    ]
    for r in results["speed"]:
        md.append(
            f"| {r['mode']} | {r['cameras']} x {r['people']} | {r['fps']:.0f} | "
            f"{r['median_fps']:.0f} | {r['cpu_fps']:.0f} | {r['cpu_median_fps']:.0f} |"
        )
    if results["real"]:
        md += [
            "",
            "## Shared real detections (pose2sim demo, 4 cameras, 100 frames, YOLO11n-pose)",
            "",
            "Reprojection error: per reconstructed joint with confidence > 0.5, the mean pixel "
            "distance between its reprojection and the 2D joints of the views it was "
            "triangulated from (undistorted image); median over all joints and frames. All "
            "views: every view of the person where the 2D joint has confidence > 0.5, used or "
            "not, with the labels as detected (so a corrected left/right swap counts as an error).",
            "",
            "| mode | frames with >= 2 people | median reprojection px | all views px "
            "| views per joint |",
            "|---|---:|---:|---:|---:|",
        ]
        for r in results["real"]:
            md.append(
                f"| {r['mode']} | {r['frames_with_2_people']}/{r['frames']} | "
                f"{r['median_reprojection_px']:.2f} | "
                f"{r['median_reprojection_all_views_px']:.2f} | {r['mean_views']:.2f} |"
            )
    save("reconstruction", results, md)


def main() -> None:
    args, head = start(__doc__)
    results = {
        **head,
        # speed first, while the process holds nothing else (the garbage collector's work
        # grows with every object alive)
        "speed": speed(args.frames),
        "accuracy": accuracy(args.frames, args.seeds),
        "real": real(),
    }
    write(results)


if __name__ == "__main__":
    main()
