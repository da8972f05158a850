"""2D detection: ms per frame per backend and input size, decoding, agreement, 3D reprojection.

On the real 4-camera videos of Pose2Sim's multi-person demo (1088x1920 portrait, 60 fps):
- decode: ms per frame of OpenCV's FFmpeg reading, all 400 frames, timed apart from detection;
- detect: ms per frame of each backend (onnx, ultralytics) at each input size, pre- and
  post-processing included, one camera per call (batch 1) and the 4 cameras of a time step in one
  call (batch 4); best and median over the repeats; 2 inference threads (the machine's cores);
- agreement: the largest keypoint or box difference between the backends, in original pixels;
- 3D: all frames through the ONNX backend at 640, then `reconstruct` with the demo's calibration:
  median reprojection error of confident joints (conf > 0.5).
Results go to benchmarks/results/detection.{md,json}.

usage: python benchmarks/detection.py [--steps 6] [--repeats 5] [--threads 2]
"""

from __future__ import annotations

import argparse
import datetime
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from stereopose.config import Config
from stereopose.detection import make_detector
from stereopose.io.cameraset import CameraSet
from stereopose.io.pose2sim_data import pose2sim_demo_dir
from stereopose.io.video import VideoFile
from stereopose.pipeline import detect_videos, reconstruct_files

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from common import machine, save

CAMERAS = ("cam01", "cam02", "cam03", "cam04")
SIZES = (320, 480, 640)


def timed(fn, repeats: int) -> tuple[float, float]:
    """Best and median seconds of fn() over repeats (after one warm-up call)."""
    fn()
    runs = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        runs.append(time.perf_counter() - t)
    return min(runs), statistics.median(runs)


def decode_ms(videos: list[Path]) -> float:
    best = float("inf")
    for _ in range(3):
        t = time.perf_counter()
        n = 0
        for v in videos:
            src = VideoFile(v)
            while src.read() is not None:
                n += 1
            src.close()
        best = min(best, (time.perf_counter() - t) / n)
    return 1000 * best


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=6, help="time steps (x 4 cameras) per timing")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--threads", type=int, default=os.cpu_count() or 2)
    args = ap.parse_args()
    videos = [pose2sim_demo_dir() / "Demo_MultiPerson" / "videos" / f"{c}.mp4" for c in CAMERAS]
    with CameraSet(videos, max_frames=args.steps) as cams:
        steps = [list(s.images.values()) for s in cams]
    results: dict = {
        "date": datetime.date.today().isoformat(),
        "machine": machine().replace("one thread", f"{args.threads} inference threads"),
        "frame": "1088x1920 portrait",
        "steps": args.steps,
        "repeats": args.repeats,
        "decode_ms_per_frame": decode_ms(videos),
        "detect": [],
    }
    print(f"decode: {results['decode_ms_per_frame']:.1f} ms per frame")
    detectors = {}
    for backend in ("onnx", "ultralytics"):
        for imgsz in SIZES:
            det = make_detector(backend, imgsz=imgsz, threads=args.threads)
            detectors[backend, imgsz] = det
            n = len(steps) * 4
            b1 = timed(lambda d=det: [d.detect([im]) for s in steps for im in s], args.repeats)
            b4 = timed(lambda d=det: [d.detect(s) for s in steps], args.repeats)
            row = {
                "backend": backend,
                "imgsz": imgsz,
                "input": "x".join(map(str, _input_shape(imgsz))),
                "batch1_ms_best": 1000 * b1[0] / n,
                "batch1_ms_median": 1000 * b1[1] / n,
                "batch4_ms_best": 1000 * b4[0] / n,
                "batch4_ms_median": 1000 * b4[1] / n,
            }
            results["detect"].append(row)
            print(row)
    results["agreement_px"] = {}
    for imgsz in SIZES:
        worst = 0.0
        for s in steps:
            a = detectors["onnx", imgsz].detect(s)
            b = detectors["ultralytics", imgsz].detect(s)
            for pa, pb in zip(a, b, strict=True):
                if len(pa) != len(pb):
                    worst = float("inf")
                elif len(pa):
                    worst = max(
                        worst,
                        float(np.abs(pa.keypoints[..., :2] - pb.keypoints[..., :2]).max()),
                        float(np.abs(pa.boxes - pb.boxes).max()),
                    )
        results["agreement_px"][imgsz] = worst
    print("agreement", results["agreement_px"])
    calib = HERE.parents[1] / "shared" / "data" / "pose2sim-demo-yolo11n" / "calib.toml"
    with tempfile.TemporaryDirectory() as tmp:
        summary = detect_videos(videos, Path(tmp) / "pose", detectors["onnx", 640])
        results["people_per_frame"] = {
            c: summary.people[c] / summary.frames[c] for c in summary.cameras
        }
        if calib.is_file():
            rec = reconstruct_files(calib, Path(tmp) / "pose", Path(tmp) / "p.jsonl", Config())
            results["reprojection_median_px"] = rec.median_confident_reprojection_px
            results["reprojection_mean_px"] = rec.mean_reprojection_px
    save("detection", results, markdown(results))


def _input_shape(imgsz: int) -> tuple[int, int]:
    from stereopose.detection.base import letterbox_for

    return letterbox_for((1920, 1088), imgsz).input_shape[::-1]


def markdown(r: dict) -> list[str]:
    md = [
        "# 2D detection (YOLO11n-pose)",
        "",
        f"{r['date']}, {r['machine']}. Real 4-camera videos of Pose2Sim's multi-person demo "
        f"({r['frame']}); {r['steps']} time steps x 4 cameras per timing, best and median of "
        f"{r['repeats']} repeats; pre- and post-processing included, decoding excluded.",
        "",
        "| backend | imgsz | input (w x h) | ms/frame, 1 camera per call | "
        "ms/frame, 4 cameras per call |",
        "|---|---|---|---|---|",
    ]
    for d in r["detect"]:
        md.append(
            f"| {d['backend']} | {d['imgsz']} | {d['input']} | {d['batch1_ms_best']:.1f} "
            f"(median {d['batch1_ms_median']:.1f}) | {d['batch4_ms_best']:.1f} "
            f"(median {d['batch4_ms_median']:.1f}) |"
        )
    md += [
        "",
        f"Decoding (OpenCV/FFmpeg, H.264 1088x1920): {r['decode_ms_per_frame']:.1f} ms per frame.",
        "",
        "Largest difference between the onnx and ultralytics backends (keypoints and boxes, "
        "original pixels): "
        + ", ".join(f"{v:.4f} px at {k}" for k, v in r["agreement_px"].items())
        + ".",
        "",
        "People per frame (onnx, 640): "
        + ", ".join(f"{c} {v:.2f}" for c, v in r["people_per_frame"].items())
        + ".",
    ]
    if "reprojection_median_px" in r:
        md.append(
            f"Detect then reconstruct with the demo calibration: median reprojection error of "
            f"confident joints {r['reprojection_median_px']:.2f} px "
            f"(mean over all joints {r['reprojection_mean_px']:.2f} px)."
        )
    return md


if __name__ == "__main__":
    main()
