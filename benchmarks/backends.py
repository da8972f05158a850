"""OpenVINO against ONNX Runtime for YOLO11n-pose on this CPU, on the real 4-camera demo.

- speed: ms per frame at imgsz 640 and 320 (a 1088x1920 portrait frame runs at 640x384 and
  320x192), the 4 cameras of a step in one call, with 1 and with 2 inference threads (median
  over the steps), for ONNX Runtime fp32, OpenVINO fp32 and OpenVINO bf16 (what OpenVINO picks
  by itself on a CPU with bfloat16 instructions);
- 2D agreement with ONNX Runtime fp32: people matched by box IoU >= 0.5, the distance of the
  joints both see (confidence >= 0.5): median, p95, max, PCK at 1, 2 and 5 px; and OpenVINO
  running ONNX Runtime's INT8 model (people found, their scores);
- 3D: `stereopose run` on the demo with each, the reprojection error of the output joints and
  the people tracked, and how far each 3D joint moved against ONNX Runtime fp32 (same frame,
  people matched by their mean joint position): median, p95, max in mm.

    python benchmarks/backends.py [--steps 25]

Results in results/backends.{json,md}, one section per kind of CPU (its model name): a run on
an AMD EPYC with AVX512_BF16 keeps the Intel Xeon with AMX's section and replaces only its own,
since bfloat16's rounding differs between the two (see the bf16 test's bounds).
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import RESULTS, machine, save
from int8 import _iou, frames  # the demo's steps, box overlap: as the INT8 benchmark reads them
from stereopose.detection import make_detector
from stereopose.detection.models import default_int8, demo_videos
from stereopose.detection.openvino_core import ov_core

VARIANTS = {  # name: (backend, precision)
    "onnxruntime_fp32": ("onnx", "fp32"),
    "openvino_fp32": ("openvino", "fp32"),
    "openvino_bf16": ("openvino", "bf16"),
    "openvino_int8": ("openvino", "int8"),  # OpenVINO's INT8 model (NNCF), its head in floats
}
IMGSZ = (640, 320)
PCK_PX = (1.0, 2.0, 5.0)


def speed(det, data: list[list[np.ndarray]]) -> float:
    det.detect(data[0])  # warm-up
    times = []
    for step in data:
        t0 = time.perf_counter()
        det.detect(step)
        times.append((time.perf_counter() - t0) * 1000 / len(step))
    return statistics.median(times)


def agreement(ref_det, det, data: list[list[np.ndarray]]) -> dict:
    dists: list[float] = []
    only_ref = only_other = matched = 0
    scores: list[float] = []
    per_step: list[np.ndarray] = []  # one step's 4 frames: what the bf16 test sees
    for step in data:
        first = len(dists)
        for a, b in zip(ref_det.detect(step), det.detect(step), strict=True):
            scores += [float(s) for s in b.scores]
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
            only_ref += len(a) - len(used_a)
            only_other += len(b) - len(used_b)
        per_step.append(np.asarray(dists[first:]))
    d = np.asarray(dists)
    steps = [x for x in per_step if x.size]
    return {
        "people_matched": matched,
        "people_only_reference": only_ref,
        "people_only_this": only_other,
        "person_score_median": float(np.median(scores)) if scores else None,
        "joints_compared": int(d.size),
        "median_px": float(np.median(d)) if d.size else None,
        "p95_px": float(np.quantile(d, 0.95)) if d.size else None,
        "max_px": float(d.max()) if d.size else None,
        **{f"pck_{t:g}px": float((d <= t).mean()) if d.size else None for t in PCK_PX},
        # the worst step's median and p95, and its worst joint
        "step_median_px_max": max((float(np.median(x)) for x in steps), default=None),
        "step_p95_px_max": max((float(np.quantile(x, 0.95)) for x in steps), default=None),
        "step_max_px_median": float(np.median([x.max() for x in steps])) if steps else None,
    }


def run_demo(backend: str, precision: str, work: Path) -> tuple[dict, Path]:
    from stereopose.pipeline.demo import write_demo_config
    from stereopose.pipeline.run import run

    config = write_demo_config(work)
    config.write_text(
        config.read_text()
        + (
            f'\n[detector]\nbackend = "{backend}"\nprecision = "{precision}"\n\n[outputs]\n'
            "trc = false\ncsv = false\noverlays = false\nreport = false\n"
        )
    )
    t0 = time.perf_counter()
    summary = run(config)
    wall = time.perf_counter() - t0
    return {
        "wall_s": wall,
        "frames": summary.frames,
        "reprojection_median_px": summary.reprojection_median_px,
        "confident_reprojection_median_px": summary.median_confident_reprojection_px,
        "tracks": len(summary.trajectories or []),
    }, work / "poses3d.jsonl"


def _poses(path: Path) -> dict[int, list[np.ndarray]]:
    out: dict[int, list[np.ndarray]] = {}
    with open(path, encoding="utf-8") as f:
        for line in f:
            rec = json.loads(line)
            out[rec["frame"]] = [
                np.array([j if j is not None else [np.nan] * 3 for j in p["joints"]], float)
                for p in rec["people"]
            ]
    return out


def joints_moved(ref: Path, other: Path) -> dict:
    """Per frame, each person of `ref` matched to the person of `other` nearest in mean joint
    position (within 0.5 m); the distance of each joint both have, mm."""
    a, b = _poses(ref), _poses(other)
    d: list[float] = []
    unmatched = 0
    for frame, people in a.items():
        others = b.get(frame, [])
        for p in people:
            centre = np.nanmean(p, axis=0)
            best, best_d = None, 0.5
            for q in others:
                dist = float(np.linalg.norm(np.nanmean(q, axis=0) - centre))
                if dist < best_d:
                    best, best_d = q, dist
            if best is None:
                unmatched += 1
                continue
            both = ~np.isnan(p).any(axis=1) & ~np.isnan(best).any(axis=1)
            d += list(1000 * np.linalg.norm(p[both] - best[both], axis=1))
    x = np.asarray(d)
    return {
        "joints": int(x.size),
        "people_unmatched": unmatched,
        "median_mm": float(np.median(x)) if x.size else None,
        "p95_mm": float(np.quantile(x, 0.95)) if x.size else None,
        "max_mm": float(x.max()) if x.size else None,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=25, help="demo steps timed and compared")
    args = ap.parse_args()
    import openvino as ov

    videos = demo_videos()
    if not videos:
        sys.exit("the demo videos are not in the cache: run `stereopose demo` once")
    data = frames(videos, args.steps)
    core = ov_core()
    r: dict = {
        "date": datetime.date.today().isoformat(),
        "machine": machine().replace(", one thread", ""),
        "cpu_capabilities": list(core.get_property("CPU", "OPTIMIZATION_CAPABILITIES")),
        "openvino": ov.__version__.split("-")[0],
        "load_average_start": os.getloadavg(),
        "steps": len(data),
    }
    ms: dict = {}
    for name, (backend, precision) in VARIANTS.items():
        for imgsz in IMGSZ:
            for n in (1, 2):
                det = make_detector(backend, imgsz=imgsz, threads=n, precision=precision)
                ms[f"{name}_{imgsz}_{n}thread"] = speed(det, data)
                print(name, imgsz, n, round(ms[f"{name}_{imgsz}_{n}thread"], 1), flush=True)
    r["ms_per_frame"] = ms
    ref = make_detector("onnx", threads=2)
    r["agreement"] = {
        name: agreement(ref, make_detector(b, threads=2, precision=p), data)
        for name, (b, p) in VARIANTS.items()
        if name != "onnxruntime_fp32"
    }
    from stereopose.detection.yolo_openvino import OpenVinoPoseDetector

    r["agreement"]["openvino_onnxruntime_int8_model"] = agreement(
        ref, OpenVinoPoseDetector(default_int8(), threads=2), data
    )
    r["agreement"]["onnxruntime_fp32_reference"] = {
        "person_score_median": agreement(ref, ref, data[:3])["person_score_median"]
    }
    with tempfile.TemporaryDirectory() as tmp:
        runs, poses = {}, {}
        for name, (b, p) in VARIANTS.items():
            runs[name], poses[name] = run_demo(b, p, Path(tmp) / name)
            print(name, runs[name], flush=True)
        r["run"] = runs
        r["joints_moved"] = {
            name: joints_moved(poses["onnxruntime_fp32"], poses[name])
            for name in VARIANTS
            if name != "onnxruntime_fp32"
        }
    r["load_average_end"] = os.getloadavg()
    cpus = _earlier()
    cpus[_cpu(r["machine"])] = r
    save("backends", {"cpus": cpus}, markdown(cpus))


def _cpu(machine_: str) -> str:
    """The kind of CPU a result was measured on: the model name of its machine line."""
    return machine_.split(",")[0].strip()


def _earlier() -> dict:
    """The sections of earlier runs, by CPU; a file from before sections is one run."""
    path = RESULTS / "backends.json"
    try:
        old = json.loads(path.read_text())
    except (OSError, ValueError):
        return {}
    if "cpus" in old:
        return dict(old["cpus"])
    return {_cpu(old["machine"]): old} if "machine" in old else {}


def markdown(cpus: dict) -> list[str]:
    md = [
        "# OpenVINO against ONNX Runtime (YOLO11n-pose, CPU)",
        "",
        "One section per kind of CPU: OpenVINO runs bf16 with AMX on an Intel Xeon and with "
        "AVX512_BF16 on an AMD EPYC, and the two round differently.",
        "",
        "bf16 against ONNX Runtime fp32, by CPU (imgsz 640; 2D joints both see with confidence "
        ">= 0.5; 3D joints of `stereopose run` on the demo):",
        "",
        "| CPU | people matched / only one | 2D median / p95 / max px | worst step's median / "
        "p95 px | PCK 5 px | 3D median / p95 mm | ms per frame, 2 threads: fp32 -> bf16 |",
        "|---|---|---|---|---|---|---|",
    ]
    for cpu, r in cpus.items():
        a, m, ms = (
            r["agreement"]["openvino_bf16"],
            r["joints_moved"]["openvino_bf16"],
            r["ms_per_frame"],
        )
        md.append(
            f"| {cpu} | {_people_2d(a)} | {_f(a.get('step_median_px_max'), 2)}"
            f" / {_f(a.get('step_p95_px_max'), 2)} | {_f(a['pck_5px'], 3)} | "
            f"{_f(m['median_mm'], 2)} / {_f(m['p95_mm'], 1)} | "
            f"{ms['onnxruntime_fp32_640_2thread']:.1f} -> {ms['openvino_bf16_640_2thread']:.1f} |"
        )
    int8 = {cpu: r for cpu, r in cpus.items() if "openvino_int8" in r["run"]}
    if int8:
        md += [
            "",
            "OpenVINO's INT8 model (NNCF, its pose head and the inside of each SiLU in floats) "
            "against ONNX Runtime fp32, by CPU: the same figures, and its speed against bf16's:",
            "",
            "| CPU | people matched / only one | 2D median / p95 / max px | 3D median / p95 mm "
            "| ms per frame, 2 threads: bf16 -> int8 | `run` wall s: bf16 -> int8 |",
            "|---|---|---|---|---|---|",
        ]
    for cpu, r in int8.items():
        a, m, ms = (
            r["agreement"]["openvino_int8"],
            r["joints_moved"]["openvino_int8"],
            r["ms_per_frame"],
        )
        md.append(
            f"| {cpu} | {_people_2d(a)} | {_f(m['median_mm'], 2)} / "
            f"{_f(m['p95_mm'], 1)} | {ms['openvino_bf16_640_2thread']:.1f} -> "
            f"{ms['openvino_int8_640_2thread']:.1f} | {r['run']['openvino_bf16']['wall_s']:.1f}"
            f" -> {r['run']['openvino_int8']['wall_s']:.1f} |"
        )
    for cpu, r in cpus.items():
        md += ["", f"## {cpu}", "", *section(r)]
    return md


def section(r: dict) -> list[str]:
    ms, ag, run, moved = r["ms_per_frame"], r["agreement"], r["run"], r["joints_moved"]
    names = [v for v in VARIANTS if v in run]  # an earlier run may lack a later variant
    md = [
        f"`python benchmarks/backends.py --steps {r['steps']}`, {r['date']}, {r['machine']} "
        f"(capabilities {', '.join(r['cpu_capabilities'])}), OpenVINO {r['openvino']}; load "
        f"average {r['load_average_start'][0]:.2f} at the start, "
        f"{r['load_average_end'][0]:.2f} at the end. {r['steps']} steps of the real 4-camera "
        "demo (1088x1920 portrait frames), the 4 frames of a step in one call.",
        "",
        "| ms per frame | " + " | ".join(n.replace("_", " ") for n in names) + " |",
        "|---|" + "---|" * len(names),
    ]
    for imgsz in IMGSZ:
        for n in (1, 2):
            md.append(
                f"| imgsz {imgsz}, {n} thread{'s' if n > 1 else ''} | "
                + " | ".join(f"{ms[f'{v}_{imgsz}_{n}thread']:.1f}" for v in names)
                + " |"
            )
    md += [
        "",
        "2D against ONNX Runtime fp32 (imgsz 640; joints both see with confidence >= 0.5):",
        "",
        "| | people matched / only ONNX Runtime / only this | joints | median px | p95 px | "
        "max px | PCK 1 / 2 / 5 px | person score median |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for name, a in ag.items():
        if "people_matched" not in a:
            continue
        md.append(
            f"| {name.replace('_', ' ')} | {a['people_matched']} / "
            f"{a['people_only_reference']} / {a['people_only_this']} | {a['joints_compared']} | "
            f"{_f(a['median_px'], 3)} | {_f(a['p95_px'], 2)} | {_f(a['max_px'], 2)} | "
            + " / ".join(_f(a[f"pck_{t:g}px"], 3) for t in PCK_PX)
            + f" | {_f(a['person_score_median'], 2)} |"
        )
    md += [
        "",
        "ONNX Runtime fp32's own person score median: "
        f"{_f(ag['onnxruntime_fp32_reference']['person_score_median'], 2)}.",
        "",
        "3D: `stereopose run` on the demo (tracking, zones, imgsz 640):",
        "",
        "| | reprojection median px | confident joints' median px | tracks | wall s | "
        "3D joints moved against ONNX Runtime fp32: median / p95 / max mm |",
        "|---|---|---|---|---|---|",
    ]
    for name in names:
        x = run[name]
        m = moved.get(name)
        mv = (
            f"{_f(m['median_mm'], 2)} / {_f(m['p95_mm'], 1)} / {_f(m['max_mm'], 1)} "
            f"({m['joints']} joints)"
            if m
            else "(the reference)"
        )
        md.append(
            f"| {name.replace('_', ' ')} | {_f(x['reprojection_median_px'], 3)} | "
            f"{_f(x['confident_reprojection_median_px'], 3)} | {x['tracks']} | "
            f"{x['wall_s']:.1f} | {mv} |"
        )
    return md


def _people_2d(a: dict) -> str:
    """The summary's cells of a variant's 2D agreement: people matched / only one; joints'
    median / p95 / max px."""
    return (
        f"{a['people_matched']} / {a['people_only_reference'] + a['people_only_this']} | "
        f"{_f(a['median_px'], 2)} / {_f(a['p95_px'], 2)} / {_f(a['max_px'], 1)}"
    )


def _f(x, nd: int) -> str:
    return "-" if x is None else f"{x:.{nd}f}"


if __name__ == "__main__":
    main()
