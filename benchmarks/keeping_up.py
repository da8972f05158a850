"""Keeping up with 4 live cameras: the real demo served as live HTTP streams, pipelined.

The 4 demo videos (1088x1920, 60 fps, H.264) are served by ffmpeg from imageio-ffmpeg in real
time as MPEG-TS over HTTP with stream copy (no re-encoding: the simulated cameras cost almost
nothing). Optionally each camera also serves a substream: the same video at a quarter of the
size (272x480), encoded once before the measurement and served the same way; with substreams,
the full streams are either decoded too (for drawn full-size clips, [input] full_streams =
"decode") or kept encoded, only demuxed into a packet ring for the clips' stream copies (the
default of `serve`, io.packets).

For each set-up the frame loop runs for `--seconds` on the pipelined cameras
(pipeline.pipelined: decoding per camera on its threads, detection on its own, 3D and the zones
on the loop's thread): steps per second, detection ms per step, latency from the oldest frame's
arrival to the end of its step (p50, p95), frames each camera grabbed, decoded and dropped,
resident memory at the start and the end, and the load average (the machine is shared).

With `--cameras 4,8,16`, 8 and 16 cameras are the demo's 4 served twice and four times under
other names (each copy with its camera's pose): the cost of that many live streams, measured
with `serve`'s default set-up (full streams kept encoded, detection on the substreams).

Results in results/keeping_up.{json,md}.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import datetime
import itertools
import os
import subprocess
import sys
import tempfile
import threading
import time
from importlib import resources
from pathlib import Path

import psutil

from common import machine, save
from stereopose.calibration.formats import load_calibration
from stereopose.config import Config, DetectorConfig
from stereopose.detection import make_detector
from stereopose.detection.models import demo_videos
from stereopose.detection.openvino_static import AFTER
from stereopose.fence import FenceMonitor, load_site
from stereopose.io.cameraset import CameraSet
from stereopose.io.packets import PacketRing
from stereopose.io.sinks.stats import SummarySink
from stereopose.io.summary import RunSummary
from stereopose.pipeline.loop import FrameLoop
from stereopose.pipeline.pipelined import PipelinedCameras
from stereopose.pipeline.sources import detecting_cameras
from stereopose.pipeline.stage3d import Stage3D
from stereopose.pipeline.step_rules import step_chain
from stereopose.types import Rig

SUB_SIZE = (272, 480)  # the substreams' width, height


def ffmpeg() -> str:
    import imageio_ffmpeg

    return imageio_ffmpeg.get_ffmpeg_exe()


def substream(video: Path, out: Path) -> Path:
    """`video` at SUB_SIZE, H.264, once (before any measurement)."""
    w, h = SUB_SIZE
    cmd = [
        ffmpeg(),
        "-loglevel",
        "error",
        "-y",
        "-i",
        str(video),
        "-an",
        "-vf",
        f"scale={w}:{h}",
        "-c:v",
        "libx264",
        "-preset",
        "veryfast",
        "-g",
        "30",
        "-pix_fmt",
        "yuv420p",
        str(out),
    ]
    subprocess.run(cmd, check=True, timeout=120)
    return out


def serve(video: Path, port: int, name: str) -> subprocess.Popen:
    cmd = [
        ffmpeg(),
        "-loglevel",
        "error",
        "-re",
        "-stream_loop",
        "-1",
        "-i",
        str(video),
        "-an",
        "-c",
        "copy",
        "-f",
        "mpegts",
        "-listen",
        "1",
        f"http://127.0.0.1:{port}/{name}.ts",
    ]
    return subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


def free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _names(videos: list[Path], copies: int) -> list[str]:
    """The cameras' names: the videos' stems, then each copy's (cam01_2, ...)."""
    return [v.stem if k == 0 else f"{v.stem}_{k + 1}" for k in range(copies) for v in videos]


def measure(
    videos: list[Path],
    subs: list[Path] | None,
    seconds: float,
    det,
    packets: bool = False,
    copies: int = 1,
    settings: DetectorConfig | None = None,
    decoders: str = "thread",
) -> dict:
    """One set-up's figures; settings: the [detector] settings of serve (regions, night,
    carried steps) around `det` (None: serve's defaults); decoders: [input] decoders (each
    live stream decoded on a thread, or in a process of its own)."""
    settings = settings or DetectorConfig()
    names = _names(videos, copies)
    servers, urls, sub_urls = [], [], []
    for name, v in zip(names, videos * copies, strict=True):
        port = free_port()
        servers.append(serve(v, port, name))
        urls.append(f"http://127.0.0.1:{port}/{name}.ts")
    for name, v in zip(names, (subs or []) * copies, strict=False):
        port = free_port()
        servers.append(serve(v, port, name))
        sub_urls.append(f"http://127.0.0.1:{port}/{name}.ts")
    time.sleep(1.0)  # ffmpeg listening (cameras retry anyway)
    calib = videos[0].parents[1] / "calibration" / "Calib.qca.txt"
    demo = load_calibration(calib)
    rig = Rig(tuple(dataclasses.replace(demo[n.split("_")[0]], name=n) for n in names))
    site = load_site(Path(str(resources.files("stereopose") / "data" / "demo_site.toml")))
    proc = psutil.Process()
    rings = {n: PacketRing(20.0, 64 * 2**20) for n in names} if packets else None
    try:
        with CameraSet(
            urls,
            names,
            detect=sub_urls or None,
            first_frame_timeout_s=30,
            packets=rings,
            decoders=decoders,
        ) as cams:
            cfg = dataclasses.replace(Config(), fps=cams.fps)
            cameras = detecting_cameras(cams, rig, det, settings, site)  # as serve does
            source = PipelinedCameras(cameras)
            stage = Stage3D(rig, cfg, calib_path=str(calib))
            summary = RunSummary(rig.names, source.stages, "", stage.tracking, live=True)
            fences = FenceMonitor(site, cfg.fps, cfg.tracking.max_lost_s)
            stop = threading.Event()
            rss_start = proc.memory_info().rss
            load_start = os.getloadavg()
            skip = {s.pid for s in servers}  # the simulated cameras are not the service
            cpu_start = _cpu(proc, skip)
            threading.Timer(seconds, stop.set).start()
            t0 = time.perf_counter()
            sinks = [SummarySink(summary)]  # the people figures (in memory)
            FrameLoop(source, stage, sinks, summary, rules=step_chain(fences), stop=stop).run()
            wall = time.perf_counter() - t0
            cpu = _cpu(proc, skip) - cpu_start
            rss_end = proc.memory_info().rss
            per_camera = {n: dataclasses.asdict(s) for n, s in cams.stats().items()}
            per_sub = {n: dataclasses.asdict(s) for n, s in cams.detect_stats().items()}
    finally:
        for s in servers:
            s.kill()
            s.wait()
    st = source.stats
    loop_s = sum(v for k, v in summary.seconds.items() if k not in ("decode", "detect"))
    carried = summary.carry or (cameras.carry.report() if cameras.carry else {})
    return {
        "cameras_n": len(names),
        "carry": settings.carry,
        "carried_share": sum(c["carried"] for c in carried.values())
        / max(sum(c["carried"] + c["detected"] for c in carried.values()), 1),
        "substreams": bool(subs),
        "full_streams": "packets" if packets else "decoded",
        "decoders": decoders,
        "cpu_s_per_step": cpu / max(st.delivered, 1),
        "packet_ring_mb": {n: r.bytes / 2**20 for n, r in (rings or {}).items()},
        "seconds": wall,
        "steps": st.delivered,
        "steps_per_s": st.delivered / wall,
        "detect_ms_per_step": 1000 * st.detect_s / max(st.detected, 1),
        "loop_ms_per_step": 1000 * loop_s / max(st.delivered, 1),
        "latency_p50_s": st.latency(0.5),
        "latency_p95_s": st.latency(0.95),
        "steps_dropped": st.dropped,
        "cameras": per_camera,
        "substream_readers": per_sub,
        "rss_mb_start": rss_start / 2**20,
        "rss_mb_end": rss_end / 2**20,
        "load_average_start": load_start,
        "load_average_end": os.getloadavg(),
        "people_frames": sum(k * v for k, v in summary.people_histogram.items()),
    }


def _cpu(proc: psutil.Process, skip: set[int]) -> float:
    """CPU seconds (user and system) of this process and its children (the decoder processes)
    but those in `skip`."""
    total = sum(proc.cpu_times()[:2])
    for child in proc.children(recursive=True):
        if child.pid in skip:
            continue
        with contextlib.suppress(psutil.Error):  # ended meanwhile
            total += sum(child.cpu_times()[:2])
    return total


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--threads", type=int, default=2, help="inference threads")
    ap.add_argument("--backend", default="auto", help="auto (the default of serve), onnx, ...")
    ap.add_argument("--precision", default="auto", choices=("auto", "fp32", "int8", "bf16"))
    ap.add_argument("--cameras", default="4", help="camera counts, e.g. 4,8,16 (see the module)")
    ap.add_argument("--name", default="keeping_up", help="the results' file name")
    ap.add_argument(
        "--decoders",
        default="thread",
        help="[input] decoders to measure with 4 cameras: thread, process, or thread,process",
    )
    ap.add_argument(
        "--no-static",
        action="store_true",
        help="every call on OpenVINO's dynamic model (no model of one shape: "
        "detection.openvino_static), for comparison",
    )
    args = ap.parse_args()
    videos = demo_videos()
    if len(videos) != 4:
        sys.exit("the demo videos are not in the cache: run `stereopose demo` once")
    counts = [int(n) for n in args.cameras.split(",")]
    if any(n % 4 or n <= 0 for n in counts):
        sys.exit("--cameras: multiples of 4 (the demo's cameras and their copies)")
    det = make_detector(backend=args.backend, threads=args.threads, precision=args.precision)
    if args.no_static and hasattr(det, "static"):
        det.static = None
    r = {
        "date": datetime.date.today().isoformat(),
        "machine": machine().replace("one thread", f"{args.threads} inference threads"),
        "precision": args.precision,
        "detector": str(getattr(det, "choice", args.backend)),
        "models_of_one_shape": bool(getattr(det, "static", None)),
        "models_of_one_shape_after": AFTER,  # calls of a shape before its model is made
        "runs": [],
    }
    with tempfile.TemporaryDirectory() as tmp:
        subs = [substream(v, Path(tmp) / f"{v.stem}_sub.mp4") for v in videos]
        for n in counts:
            setups = ((False, False, True), (True, False, True), (True, True, True))
            setups = (*setups, (True, True, False)) if n == 4 else ((True, True, True),)
            kinds = args.decoders.split(",") if n == 4 else ["thread"]
            for (use_subs, packets, carry), decoders in itertools.product(setups, kinds):
                settings = DetectorConfig(carry=carry)
                run = measure(
                    videos,
                    subs if use_subs else None,
                    args.seconds,
                    det,
                    packets,
                    n // 4,
                    settings,
                    decoders,
                )
                r["runs"].append(run)
                print(
                    f"{n} cameras, substreams={use_subs} packets={packets} carry={carry} "
                    f"decoders={decoders}: "
                    f"{run['steps_per_s']:.2f} steps/s, latency p50 "
                    f"{run['latency_p50_s']:.2f} p95 {run['latency_p95_s']:.2f} s",
                    flush=True,
                )
    save(args.name, r, markdown(r))


def _static_said(r: dict) -> str:
    """Whether OpenVINO compiled models of the shapes it met most (detection.openvino_static)."""
    if "models_of_one_shape" not in r:
        return ""
    if r["models_of_one_shape"]:
        after = r.get("models_of_one_shape_after", 128)  # the results of 2026-12-07: 128
        return f", with models of the shapes it meets most (after {after} calls of one)"
    return ", every call on OpenVINO's dynamic model (`--no-static`)"


def markdown(r: dict) -> list[str]:
    md = [
        "# Keeping up: live demo cameras, pipelined",
        "",
        f"{r['date']}, {r['machine']}, detector: {r.get('detector', r['precision'])}"
        f"{_static_said(r)}. The 4 "
        "real demo videos "
        "(1088x1920, 60 fps, H.264) served live over HTTP by ffmpeg with stream copy; "
        f"substreams: the same at {SUB_SIZE[0]}x{SUB_SIZE[1]}. Before this work `run` made "
        "0.54 steps/s on the same 4 full streams (detection 1.6 s per step). 8 and 16 "
        "cameras: the 4 served twice and four times under other names. Latency: from the "
        "oldest frame's arrival to the end of its step, when its events are out (capture to "
        "event). Detection as `serve` sets it up by default: regions (the demo site's "
        "workers watched), each camera's light, carried steps (`[detector] carry`); off: "
        "every camera detected at every step.",
        "",
        "| cameras | set-up | decoders | carried steps | steps/s | CPU s/step | detect ms/step | "
        "3D+zones ms/step | latency p50 / p95 s | steps dropped | frames grabbed / decoded per "
        "camera | RSS MB start -> end | load avg start -> end |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for run in r["runs"]:
        cams = run["cameras"].values()
        grabbed = sum(c["grabbed"] for c in cams) / len(cams)
        decoded = sum(c["decoded"] for c in cams) / len(cams)
        what = "full streams only"
        if run["substreams"]:
            what = (
                "full streams kept encoded (packets) + substreams (detect on the substream)"
                if run.get("full_streams") == "packets"
                else "full streams decoded + substreams (detect on the substream)"
            )
        carry = (
            f"on ({100 * run['carried_share']:.0f} % of camera-steps)"
            if run.get("carry")
            else "off"
        )
        md.append(
            f"| {run.get('cameras_n', 4)} | {what} | {run.get('decoders', 'thread')} | {carry} | "
            f"{run['steps_per_s']:.2f} | {run.get('cpu_s_per_step', float('nan')):.3f} | "
            f"{run['detect_ms_per_step']:.0f} | "
            f"{run['loop_ms_per_step']:.0f} | {run['latency_p50_s']:.2f} / "
            f"{run['latency_p95_s']:.2f} | {run['steps_dropped']} | {grabbed:.0f} / "
            f"{decoded:.0f} | {run['rss_mb_start']:.0f} -> {run['rss_mb_end']:.0f} | "
            f"{run['load_average_start'][0]:.2f} -> {run['load_average_end'][0]:.2f} |"
        )
    return md


if __name__ == "__main__":
    main()
