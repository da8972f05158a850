"""ONNX Runtime on a GPU (CUDA; TensorRT fp32 and fp16) for YOLO11n-pose, on the real demo.

For each provider and batch of 1, 2, 4, 8, 16 and 32 real demo frames (the 4 cameras' frames of
successive steps, 1088x1920 portrait, run at 640x384): the latency of one batch, p50 and p95 in
ms, end to end (``detect()``: letterbox and decoding on the CPU, inference on the GPU) and the
inference alone (the prepared blob through the session, copies to and from the GPU included);
the frames per second each gives; from them the cameras one GPU (one process) serves at 25 fps:
its best throughput / 25, and the largest batch whose p95 latency stays within one 40 ms frame
time (all the cameras of a step in one batch, done before the next step). TensorRT's engine
build (cold, into a fresh engine folder) and its load from that folder (a restart) in seconds.
2D agreement with ONNX Runtime fp32 on the CPU, as backends.py measures it.

Needs no PyTorch. On a GPU machine, in a fresh virtual environment, from the repository root:

    python3 -m venv /tmp/gpu && . /tmp/gpu/bin/activate
    pip install numpy opencv-python-headless 'onnxruntime-gpu[cuda,cudnn]==1.31.1'
    # TensorRT 10, which onnxruntime-gpu 1.31 is built for (PyPI's 10.x is a stub that fetches
    # from NVIDIA's index); without it the TensorRT rows are skipped, the CUDA ones still run:
    pip install --extra-index-url https://pypi.nvidia.com 'tensorrt-cu13-libs==10.*'
    PYTHONPATH=src python benchmarks/gpu.py --out benchmarks/results

(onnxruntime-gpu 1.31 is built for CUDA 13 and cuDNN 9: the [cuda,cudnn] extras bring them from
PyPI; the machine brings the driver. In the project's own venv, replace onnxruntime by it:
``pip uninstall -y onnxruntime && pip install 'onnxruntime-gpu[cuda,cudnn]==1.31.1'``.) The model
and the videos come from the cache (``stereopose models export``, ``stereopose demo``) or from
--model FILE and --videos DIR (``~/.cache/stereopose/models/yolo11n-pose.onnx`` and
``~/.cache/stereopose/pose2sim-*/Demo_MultiPerson/videos/`` copied from a machine that has them).
It runs in about 2 to 5 minutes on one GPU, most of it TensorRT's two engine builds.

Without a CUDA provider it says so and exits with status 2. ``--providers cpu --batches 1,2
--repeats 2`` runs the same code on the CPU (a dry run; results only where --out says).
Results in <out>/gpu.{json,md}.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from backends import PCK_PX, agreement
from common import machine
from int8 import frames
from stereopose.detection import ModelError
from stereopose.detection.base import letterbox_for, letterbox_image, to_blob
from stereopose.detection.models import default_onnx, demo_videos

VARIANTS = {  # name: (device, precision)
    "cuda_fp32": ("cuda", "fp32"),
    "tensorrt_fp32": ("tensorrt", "fp32"),
    "tensorrt_fp16": ("tensorrt", "fp16"),
    "cpu_fp32": ("cpu", "fp32"),  # the dry run
}
PROVIDERS = {
    "cuda": ["cuda_fp32"],
    "tensorrt": ["tensorrt_fp32", "tensorrt_fp16"],
    "cpu": ["cpu_fp32"],
}
BATCHES = (1, 2, 4, 8, 16, 32)
FPS = 25
FRAME_MS = 1000 / FPS


def gpu_info() -> dict:
    """The GPU as nvidia-smi names it (nothing where there is no nvidia-smi)."""
    if shutil.which("nvidia-smi") is None:
        return {}
    q = "name,driver_version,memory.total,memory.used"
    try:
        out = subprocess.run(
            ["nvidia-smi", f"--query-gpu={q}", "--format=csv,noheader"],
            capture_output=True,
            text=True,
            timeout=20,
        ).stdout
    except (OSError, subprocess.SubprocessError):
        return {}
    first = out.strip().splitlines()[:1]
    if not first:
        return {}
    name, driver, total, used = (x.strip() for x in first[0].split(","))
    return {"name": name, "driver": driver, "memory_total": total, "memory_used": used}


def pct(xs: list[float], q: float) -> float:
    return float(np.quantile(np.asarray(xs), q))


def time_batches(det, pool: list[np.ndarray], batches, repeats: int) -> dict:
    """Per batch size: detect() and inference-alone latency (ms) over `repeats` batches of
    frames taken in turn from `pool` (after warm-up runs), and the frames per second."""
    out = {}
    for b in batches:
        picks = [[pool[(k * b + i) % len(pool)] for i in range(b)] for k in range(repeats)]
        lb = letterbox_for(pool[0].shape[:2], det.imgsz, det.stride, auto=True)
        blobs = [to_blob([letterbox_image(im, lb) for im in batch]) for batch in picks[:3]]
        for batch in picks[:2]:  # warm-up: CUDA picks its convolutions per new shape
            det.detect(batch)
        end_to_end, infer = [], []
        for k, batch in enumerate(picks):
            t0 = time.perf_counter()
            det.detect(batch)
            end_to_end.append((time.perf_counter() - t0) * 1000)
            blob = blobs[k % len(blobs)]
            t0 = time.perf_counter()
            det._infer(blob)
            infer.append((time.perf_counter() - t0) * 1000)
        row = {"batch": b, "input": list(blobs[0].shape)}
        for name, ms in (("detect", end_to_end), ("inference", infer)):
            row[f"{name}_p50_ms"] = statistics.median(ms)
            row[f"{name}_p95_ms"] = pct(ms, 0.95)
            row[f"{name}_frames_per_s"] = b * 1000 / statistics.median(ms)
        out[str(b)] = row
        print(
            f"  batch {b:2d}: detect {row['detect_p50_ms']:7.1f} ms p50 "
            f"{row['detect_p95_ms']:7.1f} p95, inference {row['inference_p50_ms']:7.1f} ms "
            f"p50, {row['detect_frames_per_s']:6.0f} frames/s",
            flush=True,
        )
    return out


def cameras(rows: dict) -> dict:
    """Cameras at 25 fps: the best throughput / 25, and the largest batch within 40 ms (p95)."""
    out = {}
    for name in ("detect", "inference"):
        best = max(r[f"{name}_frames_per_s"] for r in rows.values())
        within = [r["batch"] for r in rows.values() if r[f"{name}_p95_ms"] <= FRAME_MS]
        out[name] = {
            "by_throughput": best / FPS,
            "largest_batch_within_40ms": max(within) if within else 0,
        }
    return out


def make(model: Path, device: str, precision: str, imgsz: int, max_batch: int):
    from stereopose.detection.yolo_onnx import OnnxPoseDetector

    return OnnxPoseDetector(
        model, imgsz=imgsz, device=device, precision=precision, max_batch=max_batch
    )


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--providers", default="cuda,tensorrt", help="cuda, tensorrt, cpu (dry run)")
    ap.add_argument("--batches", default=",".join(map(str, BATCHES)))
    ap.add_argument("--repeats", type=int, default=20, help="timed batches per batch size")
    ap.add_argument("--steps", type=int, default=8, help="demo steps read (4 frames each)")
    ap.add_argument("--imgsz", type=int, default=640)
    ap.add_argument("--model", type=Path, help="the ONNX model (default: the cache's)")
    ap.add_argument("--videos", type=Path, help="a folder of the demo's cam*.mp4")
    ap.add_argument("--out", type=Path, help="where gpu.json and gpu.md go")
    args = ap.parse_args()
    kinds = [p.strip() for p in args.providers.split(",") if p.strip()]
    if not kinds or any(k not in PROVIDERS for k in kinds):
        return _fail(f"--providers: expected some of {', '.join(PROVIDERS)}, got {args.providers}")
    batches = [int(b) for b in args.batches.split(",")]
    dry = kinds == ["cpu"]
    if not dry and args.out is None:
        args.out = Path(__file__).resolve().parent / "results"
    try:
        import onnxruntime as ort
    except ImportError:
        return _fail("no onnxruntime here: pip install 'onnxruntime-gpu[cuda,cudnn]' (see --help)")
    available = ort.get_available_providers()
    if not dry and "CUDAExecutionProvider" not in available:
        return _fail(
            f"no CUDA provider in this ONNX Runtime ({ort.__version__}, providers: "
            f"{', '.join(available)}): this needs a GPU machine and onnxruntime-gpu "
            "(pip install 'onnxruntime-gpu[cuda,cudnn]'; see --help); nothing measured"
        )
    try:
        model = args.model or default_onnx(export=False)
    except ModelError as e:
        return _fail(f"{e} (or --model FILE)")
    videos = sorted(args.videos.glob("*.mp4")) if args.videos else demo_videos()
    if not videos:
        return _fail("no demo videos: run `stereopose demo` once, or --videos DIR")
    data = frames(videos, args.steps)
    if not data:
        return _fail(f"no frames could be read from {', '.join(map(str, videos))}")
    pool = [im for step in data for im in step]
    r: dict = {
        "date": datetime.date.today().isoformat(),
        "machine": machine().replace(", one thread", ""),
        "gpu": gpu_info(),
        "onnxruntime": ort.__version__,
        "available_providers": available,
        "model": model.name,
        "imgsz": args.imgsz,
        "frames": f"{len(pool)} frames of {len(videos)} cameras, {pool[0].shape[1]}x"
        f"{pool[0].shape[0]}",
        "repeats": args.repeats,
        "variants": {},
        "skipped": {},
    }
    print(f"onnxruntime {ort.__version__}, {available}, gpu {r['gpu'] or 'none found'}")
    ref = make(model, "cpu", "fp32", args.imgsz, max(batches))
    engines = Path(tempfile.mkdtemp(prefix="stereopose-trt-"))
    os.environ["STEREOPOSE_CACHE"] = str(engines)  # a cold engine folder for the build's time
    try:
        for kind in kinds:
            for name in PROVIDERS[kind]:
                device, precision = VARIANTS[name]
                print(name, flush=True)
                try:
                    v = variant(model, device, precision, args, batches, pool, data, ref)
                except ModelError as e:
                    if kind != "tensorrt":
                        return _fail(f"{name}: {e}")
                    r["skipped"][name] = str(e)  # TensorRT's libraries missing: CUDA still runs
                    print(f"  skipped: {e}", flush=True)
                    continue
                except Exception as e:  # an engine that did not build: keep the other rows
                    if kind != "tensorrt":
                        raise
                    r["skipped"][name] = f"{type(e).__name__}: {e}"
                    print(f"  failed: {r['skipped'][name]}", flush=True)
                    continue
                r["variants"][name] = v
    finally:
        shutil.rmtree(engines, ignore_errors=True)
    r["gpu_after"] = gpu_info()
    md = markdown(r)
    if args.out is None:
        print("\n".join(md))
        return 0
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "gpu.json").write_text(json.dumps(r, indent=2) + "\n")
    (args.out / "gpu.md").write_text("\n".join(md) + "\n")
    print(f"written {args.out / 'gpu.md'}")
    return 0


def variant(model, device, precision, args, batches, pool, data, ref) -> dict:
    t0 = time.perf_counter()
    det = make(model, device, precision, args.imgsz, max(batches))
    det.detect(pool[: max(batches)])  # TensorRT builds its engine by the first run
    first_s = time.perf_counter() - t0
    v: dict = {
        "device": device,
        "precision": precision,
        "providers": det.providers,
        "first_session_and_run_s": first_s,
    }
    if device == "tensorrt":  # a restart: the engine from the folder the first one wrote
        del det
        t0 = time.perf_counter()
        det = make(model, device, precision, args.imgsz, max(batches))
        det.detect(pool[: max(batches)])
        v["cached_session_and_run_s"] = time.perf_counter() - t0
    v["batches"] = time_batches(det, pool, batches, args.repeats)
    v["cameras_at_25fps"] = cameras(v["batches"])
    v["agreement"] = agreement(ref, det, data)
    return v


def markdown(r: dict) -> list[str]:
    gpu = r["gpu"]
    where = (
        f"{gpu['name']} (driver {gpu['driver']}, {gpu['memory_total']})"
        if gpu
        else "no GPU found by nvidia-smi"
    )
    md = [
        "# YOLO11n-pose on a GPU: ONNX Runtime's CUDA and TensorRT providers",
        "",
        f"`python benchmarks/gpu.py`, {r['date']}, {where}; {r['machine']}; ONNX Runtime "
        f"{r['onnxruntime']}. {r['frames']} (the real demo), imgsz {r['imgsz']}; "
        f"{r['repeats']} timed batches per size after 2 warm-up ones.",
        "",
        "Latency of one batch (ms, p50 / p95): detect = letterbox + inference + decoding, as the "
        "pipeline calls it for one step; inference = the session's run alone (copies to and "
        "from the GPU included).",
        "",
    ]
    for name, v in r["variants"].items():
        md += [
            f"## {name.replace('_', ' ')}",
            "",
            f"Providers: {', '.join(v['providers'])}. First session and run "
            f"{v['first_session_and_run_s']:.1f} s"
            + (
                f" (TensorRT's engine built); from the engine cache "
                f"{v['cached_session_and_run_s']:.1f} s"
                if "cached_session_and_run_s" in v
                else ""
            )
            + ".",
            "",
            "| batch | input | detect p50 / p95 ms | inference p50 / p95 ms | frames/s detect | "
            "frames/s inference |",
            "|---|---|---|---|---|---|",
        ]
        for row in v["batches"].values():
            md.append(
                f"| {row['batch']} | {'x'.join(map(str, row['input'][2:]))} | "
                f"{row['detect_p50_ms']:.1f} / {row['detect_p95_ms']:.1f} | "
                f"{row['inference_p50_ms']:.1f} / {row['inference_p95_ms']:.1f} | "
                f"{row['detect_frames_per_s']:.0f} | {row['inference_frames_per_s']:.0f} "
                "|"
            )
        md.append("")
    md += [
        "## Cameras per GPU at 25 fps",
        "",
        "By throughput: the best frames/s / 25. Within 40 ms: the largest batch (all the cameras "
        "of a step) whose p95 latency fits one frame time.",
        "",
        "| | by throughput, detect | by throughput, inference | largest batch within 40 ms, "
        "detect | within 40 ms, inference |",
        "|---|---|---|---|---|",
    ]
    for name, v in r["variants"].items():
        c = v["cameras_at_25fps"]
        md.append(
            f"| {name.replace('_', ' ')} | {c['detect']['by_throughput']:.1f} | "
            f"{c['inference']['by_throughput']:.1f} | "
            f"{c['detect']['largest_batch_within_40ms']} | "
            f"{c['inference']['largest_batch_within_40ms']} |"
        )
    md += [
        "",
        "## 2D against ONNX Runtime fp32 on the CPU",
        "",
        "| | people matched / only CPU / only this | joints | median px | p95 px | max px | "
        "PCK 1 / 2 / 5 px |",
        "|---|---|---|---|---|---|---|",
    ]
    for name, v in r["variants"].items():
        a = v["agreement"]
        md.append(
            f"| {name.replace('_', ' ')} | {a['people_matched']} / "
            f"{a['people_only_reference']} / {a['people_only_this']} | "
            f"{a['joints_compared']} | {_f(a['median_px'], 3)} | {_f(a['p95_px'], 2)} | "
            f"{_f(a['max_px'], 2)} | " + " / ".join(_f(a[f"pck_{t:g}px"], 3) for t in PCK_PX) + " |"
        )
    for name, why in r["skipped"].items():
        md += ["", f"{name.replace('_', ' ')}: not measured ({why})."]
    return md


def _f(x, nd: int) -> str:
    return "-" if x is None else f"{x:.{nd}f}"


def _fail(message: str) -> int:
    print(f"gpu.py: {message}", file=sys.stderr)
    return 2


if __name__ == "__main__":
    sys.exit(main())
