# ruff: noqa: E501  (the results tables are written line by line)
"""OpenVINO's models of one shape (detection.openvino_static) against its dynamic model: the
time of a call of each kind a step makes, on the real demo's frames, and what compiling one
costs.

For the detector `auto` chooses here (OpenVINO bf16 on a CPU with bfloat16 instructions, else
the precision asked): four whole demo frames in one call (split over the two streams, 2 + 2),
one whole frame, and 1, 2 and 4 regions (crops of the people at region_imgsz 320). Each is
timed --repeat times (the median) on a detector whose calls all run on the dynamic model, and
on one that has made the model of that call's shape (after AFTER calls of it, as a service
does); the compile's time, and the largest joint difference between the two.

usage: python benchmarks/static_shapes.py [--repeat 30] [--precision bf16]
Results: benchmarks/results/static_shapes.{md,json}.
"""

from __future__ import annotations

import argparse
import datetime
import statistics
import time

import numpy as np

from call_cost import _frames  # frame 50 of the demo's 4 cameras
from common import machine, save
from stereopose.detection import make_detector
from stereopose.detection.openvino_static import AFTER, MOST


def _crops(frames: list[np.ndarray], det) -> list[np.ndarray]:
    """A square around each person the detector finds in the frames, as regions cut them."""
    out = []
    for image, poses in zip(frames, det.detect(frames), strict=True):
        for x0, y0, x1, y1 in poses.boxes:
            side = int(max(x1 - x0, y1 - y0) * 1.2)
            cx, cy = int((x0 + x1) / 2), int((y0 + y1) / 2)
            top, left = max(cy - side // 2, 0), max(cx - side // 2, 0)
            out.append(image[top : top + side, left : left + side])
    return out


def _time(det, images, imgsz, repeat: int) -> tuple[float, list]:
    got = det.detect(images, imgsz=imgsz)
    runs = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        got = det.detect(images, imgsz=imgsz)
        runs.append(time.perf_counter() - t0)
    return 1000 * statistics.median(runs), got


def _moved(a, b) -> float:
    worst = 0.0
    for p, q in zip(a, b, strict=True):
        if len(p) != len(q):
            return float("inf")
        if len(p):
            worst = max(worst, float(np.abs(p.keypoints[..., :2] - q.keypoints[..., :2]).max()))
    return worst


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=30)
    ap.add_argument("--precision", default="auto")
    args = ap.parse_args()
    frames = _frames()
    backend = "auto" if args.precision == "auto" else "openvino"
    probe = make_detector(backend, precision=args.precision, threads=2)
    if probe.name != "openvino":
        raise SystemExit(f"auto runs {probe.name} here: models of one shape are OpenVINO's")
    crops = _crops(frames, probe)
    cases = {
        "4 whole frames": (frames, None),
        "1 whole frame": (frames[:1], None),
        "1 region": (crops[:1], 320),
        "2 regions": (crops[:2], 320),
        "4 regions": (crops[:4], 320),
    }
    rows = []
    for name, (images, imgsz) in cases.items():
        dynamic = make_detector(backend, precision=args.precision, threads=2)
        dynamic.static = None  # every call on the dynamic model
        ms_dynamic, got_dynamic = _time(dynamic, images, imgsz, args.repeat)
        own = make_detector(backend, precision=args.precision, threads=2)
        for _ in range(AFTER):
            own.detect(images, imgsz=imgsz)
        ms_static, got_static = _time(own, images, imgsz, args.repeat)
        rows.append(
            {
                "call": name,
                "images": len(images),
                "dynamic_ms": round(ms_dynamic, 2),
                "static_ms": round(ms_static, 2),
                "speedup": round(ms_dynamic / ms_static, 3),
                "shapes": [list(k) for k in own.static.shapes],
                "compile_ms": round(own.static.compile_ms, 1),
                "joints_moved_max_px": round(_moved(got_dynamic, got_static), 3),
            }
        )
        print(rows[-1], flush=True)
    r = {
        "date": datetime.date.today().isoformat(),
        "machine": machine().replace(", one thread", ", 2 inference threads"),
        "detector": f"{probe.name} {probe.precision} ({probe.runs_in})",
        "after": AFTER,
        "most": MOST,
        "repeat": args.repeat,
        "rows": rows,
    }
    save("static_shapes", r, markdown(r))


def markdown(r: dict) -> list[str]:
    md = [
        "# OpenVINO's models of one shape against its dynamic model",
        "",
        f"`python benchmarks/static_shapes.py --repeat {r['repeat']}`, {r['date']}, {r['machine']}, "
        f"detector {r['detector']}. Frame 50 of the real demo's 4 cameras (1088x1920); regions: a "
        "square of 1.2 times each person's box, at region_imgsz 320. Each call the median of "
        f"{r['repeat']} after a warm-up, on a detector whose calls all run on the dynamic model and "
        f"on one that has compiled the model of that call's shape (after {r['after']} calls of it; "
        f"at most {r['most']} per detector).",
        "",
        "| call | dynamic model ms | model of its shape ms | faster | compiled for (way, batch, h, w) | compile ms | joints moved, max px |",
        "|---|---|---|---|---|---|---|",
    ]
    for x in r["rows"]:
        shapes = "; ".join(", ".join(map(str, s)) for s in x["shapes"])
        md.append(
            f"| {x['call']} | {x['dynamic_ms']:.1f} | {x['static_ms']:.1f} | {x['speedup']:.2f}x | "
            f"{shapes} | {x['compile_ms']:.0f} | {x['joints_moved_max_px']:.2f} |"
        )
    return md


if __name__ == "__main__":
    main()
