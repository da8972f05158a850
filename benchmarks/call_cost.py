# ruff: noqa: E501  (the results tables are written line by line)
"""The detector's cost per model call on this machine: a fixed part and a part per image, for
whole frames (640) and for regions (320 crops), so that the choice between one call and
several, regions and whole frames, can be priced on the CPU at hand (Intel's AMX pays a large
fixed part per call; an AMD with AVX-512 hides it).

For each backend (the one `auto` chooses here, and ONNX Runtime fp32, the reference path):
- whole demo frames letterboxed to 640, batches of 1-4 in one call, and 4 frames split 3 + 1;
- 320 x 320 crops of the people (regions), batches of 1, 2, 4 and 8 in one call;
each the median of --repeat calls after a warm-up; a line t(k) = fixed + k x per image fitted
per input size by least squares. Then the prices the service itself measures at its start
(detection.call_costs: batches of 1-4 whole frames and 1-8 crops) and what they make it do
with a few kinds of step (detection.call_costs.cheapest): which cameras go whole; and the
calls each batch is made in at those prices (detection.call_costs.split).
Results: benchmarks/results/call_cost.{md,json}.

usage: python benchmarks/call_cost.py [--repeat 15] [--threads 2]
"""

from __future__ import annotations

import argparse
import datetime
import statistics
import time

import cv2
import numpy as np

from common import machine, save
from stereopose.detection import make_detector
from stereopose.detection.call_costs import CallCosts, cheapest
from stereopose.detection.models import demo_videos


def _frames() -> list[np.ndarray]:
    out = []
    for v in demo_videos():
        cap = cv2.VideoCapture(str(v))
        cap.set(cv2.CAP_PROP_POS_FRAMES, 50)
        ok, im = cap.read()
        cap.release()
        if not ok:
            raise SystemExit(f"{v}: no frame 50")
        out.append(im)
    if len(out) != 4:
        raise SystemExit("the demo videos are not in the cache: run `make install`")
    return out


def _timed(det, images, imgsz: int, repeat: int) -> float:
    det.detect(images, imgsz=imgsz)  # warm-up (a new shape compiles)
    runs = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        det.detect(images, imgsz=imgsz)
        runs.append(time.perf_counter() - t0)
    return 1000 * statistics.median(runs)


def _fit(ks: list[int], ms: list[float]) -> tuple[float, float]:
    slope, fixed = np.polyfit(np.array(ks, float), np.array(ms, float), 1)
    return float(fixed), float(slope)


def measure(backend: str, precision: str, threads: int, repeat: int) -> dict:
    det = make_detector(backend=backend, precision=precision, threads=threads)
    frames = _frames()
    h, w = frames[0].shape[:2]
    crop = frames[0][h // 3 : h // 3 + 600, max(0, w // 2 - 300) : w // 2 + 300]
    whole = {k: _timed(det, frames[:k], 640, repeat) for k in (1, 2, 3, 4)}
    split = _timed(det, frames[:3], 640, repeat) + _timed(det, frames[3:], 640, repeat)
    crops = {k: _timed(det, [crop] * k, 320, repeat) for k in (1, 2, 4, 8)}
    fw, pw = _fit(list(whole), list(whole.values()))
    fc, pc = _fit(list(crops), list(crops.values()))
    wide, square = (640, 384), (320, 320)  # a portrait full-HD frame at 640, a region
    prices = CallCosts(det)
    prices.ensure({wide: 4, square: 8})
    steps = {
        "3 whole, 1 camera with 1 region": ([wide] * 3, [("cam04", wide, 1)]),
        "2 whole, 2 cameras with 1 region": ([wide] * 2, [("cam03", wide, 1), ("cam04", wide, 1)]),
        "1 whole, 3 cameras with 1 region": ([wide], [(f"cam0{k}", wide, 1) for k in (2, 3, 4)]),
        "4 cameras with 2 regions": ([], [(f"cam0{k}", wide, 2) for k in (1, 2, 3, 4)]),
    }
    return {
        "detector": str(getattr(det, "choice", backend)),
        "whole_ms": whole,
        "whole_split_3_1_ms": split,
        "crops_ms": crops,
        "whole_fixed_ms": fw,
        "whole_per_image_ms": pw,
        "crop_fixed_ms": fc,
        "crop_per_image_ms": pc,
        "prices_ms": prices.table(),
        # the calls each batch is made in (CallCosts.split: two where they cost 5 % less)
        "splits": {
            f"{h}x{w}": {n: prices.split((h, w), n) for n in range(1, k + 1)}
            for (h, w), k in ((wide, 4), (square, 8))
        },
        "taken_whole": {
            k: [len(cheapest(prices, w, square, c)), len(c)] for k, (w, c) in steps.items()
        },
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=15)
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args()
    res = {
        "date": datetime.date.today().isoformat(),
        "machine": machine().replace("one thread", f"{args.threads} inference threads"),
        "backends": {
            "auto": measure("auto", "auto", args.threads, args.repeat),
            "onnx fp32": measure("onnx", "fp32", args.threads, args.repeat),
        },
    }
    md = [
        "# The detector's cost per call",
        "",
        f"{res['date']}, {res['machine']}. `python benchmarks/call_cost.py` (median of {args.repeat} calls).",
        "",
        "| backend | whole frames 1 / 2 / 3 / 4 in one call, ms | 4 as 3 + 1, ms | fixed + per frame, ms | 320 crops 1 / 2 / 4 / 8 in one call, ms | fixed + per crop, ms | 4 crops against 1 whole frame |",
        "|---|---|---|---|---|---|---|",
    ]
    for name, b in res["backends"].items():
        wm, cm = b["whole_ms"], b["crops_ms"]
        md.append(
            f"| {name} ({b['detector'].split(' (')[0]}) | {' / '.join(f'{v:.1f}' for v in wm.values())} | {b['whole_split_3_1_ms']:.1f} | "
            f"{b['whole_fixed_ms']:.1f} + {b['whole_per_image_ms']:.1f} | {' / '.join(f'{v:.1f}' for v in cm.values())} | "
            f"{b['crop_fixed_ms']:.1f} + {b['crop_per_image_ms']:.1f} | {cm[4] / wm[1]:.2f}x |"
        )
    md += [
        "",
        "The prices `serve` and `run` measure at their first step (ms for batches of 1, 2, ... in one call; `detection.call_costs`), and the cameras that may go either way that they detect whole for a few kinds of step of the demo's 4 cameras:",
        "",
        "| backend | whole frames (640x384) | 320 crops | "
        + " | ".join(res["backends"]["auto"]["taken_whole"])
        + " |",
        "|---|---|---|" + "---|" * len(res["backends"]["auto"]["taken_whole"]),
    ]
    for name, b in res["backends"].items():
        t = b["prices_ms"]
        md.append(
            f"| {name} | {' / '.join(f'{v:.1f}' for v in t['640x384'])} | {' / '.join(f'{v:.1f}' for v in t['320x320'])} | "
            + " | ".join(f"{a} of {n}" for a, n in b["taken_whole"].values())
            + " |"
        )
    md += [
        "",
        "The calls a batch is made in at those prices (`CallCosts.split`: two or more only where "
        "they cost at least 5 % less than one; + between calls):",
        "",
        "| backend | whole frames 1 / 2 / 3 / 4 | 320 crops 1 / 2 / ... / 8 |",
        "|---|---|---|",
    ]
    for name, b in res["backends"].items():
        sp = b["splits"]
        md.append(
            f"| {name} | "
            + " / ".join("+".join(map(str, c)) for c in sp["640x384"].values())
            + " | "
            + " / ".join("+".join(map(str, c)) for c in sp["320x320"].values())
            + " |"
        )
    md += [
        "",
        "The fixed part is what every extra call costs whatever its size: where it is large against",
        "the per-image part, a step's regions and whole frames belong in as few calls as possible.",
    ]
    save("call_cost", res, md)
    print("\n".join(md))


if __name__ == "__main__":
    main()
