"""INT8 against FP32 YOLO11n-pose on ONNX Runtime, on the real 4-camera demo.

- speed: ms per frame at imgsz 640 (a 1088x1920 frame runs at 384x640), the 4 cameras of a
  step in one call, with 1 and with 2 inference threads (median over the steps);
- keypoint agreement: INT8 people matched to FP32 people in each image (greedy, by box IoU
  >= 0.5), PCK of the joints both see (confidence >= 0.5) at 2, 5 and 10 px, and the people
  found by one and not the other;
- 3D: `stereopose run` on the demo with each model (tracking, zones), the reprojection error
  of the output joints (median, px) and the people tracked.

Results in results/int8.{json,md}.
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

import cv2
import numpy as np

from common import machine, save
from stereopose.detection import make_detector
from stereopose.detection.models import default_int8, default_onnx, demo_videos

THRESHOLDS_PX = (2.0, 5.0, 10.0)


def frames(videos: list[Path], steps: int) -> list[list[np.ndarray]]:
    caps = [cv2.VideoCapture(str(v), cv2.CAP_FFMPEG) for v in videos]
    out = []
    for _ in range(steps):
        step = [c.read()[1] for c in caps]
        if any(im is None for im in step):
            break
        out.append(step)
    for c in caps:
        c.release()
    return out


def speed(model: Path, data: list[list[np.ndarray]], threads: int) -> float:
    det = make_detector("onnx", model, threads=threads)
    det.detect(data[0])  # warm-up
    times = []
    for step in data:
        t0 = time.perf_counter()
        det.detect(step)
        times.append((time.perf_counter() - t0) * 1000 / len(step))
    return statistics.median(times)


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    x1, y1 = max(a[0], b[0]), max(a[1], b[1])
    x2, y2 = min(a[2], b[2]), min(a[3], b[3])
    inter = max(0.0, x2 - x1) * max(0.0, y2 - y1)
    union = (a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - inter
    return inter / union if union > 0 else 0.0


def agreement(fp32: Path, int8: Path, data: list[list[np.ndarray]]) -> dict:
    ref, q = make_detector("onnx", fp32), make_detector("onnx", int8)
    dists: list[float] = []
    only_fp32 = only_int8 = matched = 0
    for step in data:
        for a, b in zip(ref.detect(step), q.detect(step), strict=True):
            pairs = sorted(
                (
                    (_iou(a.boxes[i], b.boxes[j]), i, j)
                    for i in range(len(a))
                    for j in range(len(b))
                ),
                reverse=True,
            )
            used_a, used_b = set(), set()
            for iou, i, j in pairs:
                if iou < 0.5 or i in used_a or j in used_b:
                    continue
                used_a.add(i)
                used_b.add(j)
                ka, kb = a.keypoints[i], b.keypoints[j]
                both = (ka[:, 2] >= 0.5) & (kb[:, 2] >= 0.5)
                dists += list(np.linalg.norm(ka[both, :2] - kb[both, :2], axis=1))
            matched += len(used_a)
            only_fp32 += len(a) - len(used_a)
            only_int8 += len(b) - len(used_b)
    d = np.asarray(dists)
    return {
        "people_matched": matched,
        "people_only_fp32": only_fp32,
        "people_only_int8": only_int8,
        "joints_compared": int(d.size),
        "median_px": float(np.median(d)) if d.size else None,
        **{f"pck_{t:g}px": float((d <= t).mean()) if d.size else None for t in THRESHOLDS_PX},
    }


def run_demo(model: Path, work: Path) -> dict:
    from stereopose.pipeline.demo import write_demo_config
    from stereopose.pipeline.run import run

    config = write_demo_config(work)
    text = config.read_text() + (
        f'\n[detector]\nmodel = "{model}"\n\n[outputs]\ntrc = false\ncsv = false\n'
        "overlays = false\nreport = false\n"
    )
    config.write_text(text)
    t0 = time.perf_counter()
    summary = run(config)
    wall = time.perf_counter() - t0
    return {
        "wall_s": wall,
        "frames": summary.frames,
        "reprojection_median_px": summary.reprojection_median_px,
        "reprojection_mean_px": summary.mean_reprojection_px,
        "confident_reprojection_median_px": summary.median_confident_reprojection_px,
        "tracks": len(summary.trajectories or []),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=25, help="demo steps timed and compared")
    args = ap.parse_args()
    videos = demo_videos()
    if not videos:
        sys.exit("the demo videos are not in the cache: run `stereopose demo` once")
    fp32, int8 = default_onnx(), default_int8()
    data = frames(videos, args.steps)
    r: dict = {
        "date": datetime.date.today().isoformat(),
        "machine": machine().replace(", one thread", ""),
        "load_average_start": os.getloadavg(),
        "steps": len(data),
        "models": {"fp32": str(fp32), "int8": str(int8)},
        "model_bytes": {"fp32": fp32.stat().st_size, "int8": int8.stat().st_size},
    }
    r["ms_per_frame"] = {
        f"{p}_{n}thread": speed(m, data, n)
        for p, m in (("fp32", fp32), ("int8", int8))
        for n in (1, 2)
    }
    r["agreement"] = agreement(fp32, int8, data)
    with tempfile.TemporaryDirectory() as tmp:
        r["run"] = {p: run_demo(m, Path(tmp) / p) for p, m in (("fp32", fp32), ("int8", int8))}
    r["load_average_end"] = os.getloadavg()
    save("int8", r, markdown(r))


def markdown(r: dict) -> list[str]:
    ms, a, run = r["ms_per_frame"], r["agreement"], r["run"]
    pck = ", ".join(f"{a[f'pck_{t:g}px']:.3f} at {t:g} px" for t in THRESHOLDS_PX)
    return [
        "# INT8 against FP32 (YOLO11n-pose, ONNX Runtime)",
        "",
        f"{r['date']}, {r['machine']}; load average {r['load_average_start'][0]:.2f} at the "
        f"start, {r['load_average_end'][0]:.2f} at the end (the machine is shared). "
        f"{r['steps']} steps of the real 4-camera demo (1088x1920, run at 384x640).",
        "",
        "| | FP32 | INT8 |",
        "|---|---|---|",
        f"| ms per frame, 1 thread | {ms['fp32_1thread']:.1f} | {ms['int8_1thread']:.1f} |",
        f"| ms per frame, 2 threads | {ms['fp32_2thread']:.1f} | {ms['int8_2thread']:.1f} |",
        f"| model size, MB | {r['model_bytes']['fp32'] / 1e6:.1f} | "
        f"{r['model_bytes']['int8'] / 1e6:.1f} |",
        f"| `run` on the demo: reprojection median, px | "
        f"{run['fp32']['reprojection_median_px']:.2f} | "
        f"{run['int8']['reprojection_median_px']:.2f} |",
        f"| `run` on the demo: tracks | {run['fp32']['tracks']} | {run['int8']['tracks']} |",
        f"| `run` on the demo: wall s ({run['fp32']['frames']} steps) | "
        f"{run['fp32']['wall_s']:.1f} | {run['int8']['wall_s']:.1f} |",
        "",
        f"Keypoints: {a['people_matched']} people matched (FP32 only: {a['people_only_fp32']}, "
        f"INT8 only: {a['people_only_int8']}); over {a['joints_compared']} joints both see, "
        f"INT8 lies within {pck} of FP32 (median {a['median_px']:.2f} px).",
    ]


if __name__ == "__main__":
    main()
