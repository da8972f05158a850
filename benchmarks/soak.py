"""Soak: `stereopose serve` for a long while on the real demo as 4 live HTTP cameras.

Each of Pose2Sim's 4 demo videos (1088x1920, 60 fps, H.264) is made once into a clip played
forward then backward (so that people do not jump where the stream loops), then served by
ffmpeg (imageio-ffmpeg) in real time, looped, as MPEG-TS over HTTP with stream copy: no
re-encoding while it runs, so the figures measure stereopose, not the simulated cameras. A
camera server that ends (its client reconnected) is started again at once, and counted.

`stereopose serve` runs on them (health and metrics on a free 127.0.0.1 port, MQTT off);
every --every-s seconds this script samples the service's resident memory (/proc), its
/api/health (cameras, dropped frames, storage) and /metrics (steps, end-to-end latency,
stages). At the end it stops the service with SIGTERM, as systemd does, and writes
benchmarks/results/soak.{md,json}: resident memory after the warm-up and at the end (the aim:
growth under 5 %), storage against its cap, steps/s, latency p50/p95 and dropped frames.

usage: python benchmarks/soak.py [--duration-s 1800] [--every-s 10] [--warmup-s 120]
                                 [--imgsz 640] [--detect-fps F] [--max-gb 1] [--segment-s 300]
"""

from __future__ import annotations

import argparse
import contextlib
import datetime
import json
import math
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
import urllib.error
import urllib.request
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(HERE))
from prometheus_client.parser import text_string_to_metric_families

from common import machine, save
from stereopose.io.pose2sim_data import pose2sim_demo_dir
from stereopose.pipeline.demo import CAMERAS, write_serve_demo_config

E2E = "stereopose_end_to_end_latency_seconds"
STAGES = "stereopose_stage_seconds"


def ffmpeg() -> str:
    import imageio_ffmpeg

    return imageio_ffmpeg.get_ffmpeg_exe()


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def palindrome(video: Path, out: Path, scale: str | None = None) -> Path:
    """``video`` then the same frames backward, as H.264 with a keyframe each second (made
    once, before the soak; the stream itself is then only copied)."""
    if out.is_file():
        return out
    out.parent.mkdir(parents=True, exist_ok=True)
    part = out.with_suffix(".part.mp4")
    cmd = [
        ffmpeg(),
        "-loglevel",
        "error",
        "-y",
        "-i",
        str(video),
        "-filter_complex",
        (
            "[0:v]"
            + (f"scale={scale}," if scale else "")
            + "split[a][b];[b]reverse[r];[a][r]concat=n=2:v=1:a=0[v]"
        ),
        "-map",
        "[v]",
        "-c:v",
        "libx264",
        "-preset",
        "veryfast",
        "-crf",
        "20",
        "-g",
        "60",
        "-pix_fmt",
        "yuv420p",
        "-an",
        str(part),
    ]
    subprocess.run(cmd, check=True, timeout=600)
    os.replace(part, out)
    return out


class Camera:
    """ffmpeg serving one looped video, in real time, stream copied, to one HTTP client at a
    time; started again whenever it ends (a client that reconnects ends the previous one)."""

    def __init__(self, video: Path, name: str) -> None:
        self.video, self.name, self.port = video, name, free_port()
        self.url = f"http://127.0.0.1:{self.port}/{name}.ts"
        self.restarts = -1  # the first start is not a restart
        self._proc: subprocess.Popen | None = None
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._thread = threading.Thread(target=self._keep, name=f"camera {name}", daemon=True)

    def start(self) -> Camera:
        self._thread.start()
        return self

    def _keep(self) -> None:
        cmd = [
            ffmpeg(),
            "-loglevel",
            "error",
            "-re",
            "-stream_loop",
            "-1",
            "-i",
            str(self.video),
            "-an",
            "-c:v",
            "copy",
            "-f",
            "mpegts",
            "-listen",
            "1",
            self.url,
        ]
        while not self._stop.is_set():
            with self._lock:
                if self._stop.is_set():
                    return
                self._proc = subprocess.Popen(
                    cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
                )
                self.restarts += 1
            self._proc.wait()
            self._stop.wait(0.2)  # a server that cannot start is not restarted in a busy loop

    def listening(self) -> bool:
        with socket.socket() as s:
            s.settimeout(0.5)
            return s.connect_ex(("127.0.0.1", self.port)) == 0

    def stop(self) -> None:
        with self._lock:
            self._stop.set()
            if self._proc is not None and self._proc.poll() is None:
                self._proc.kill()
                self._proc.wait()
        self._thread.join(timeout=5)


def write_config(
    work: Path, cameras: list[Camera], port: int, args, subs: dict[str, Camera] | None = None
) -> Path:
    """The serve demo's configuration with the live cameras as sources (and their substreams
    as their `detect` sources) and the soak's storage settings."""
    path = write_serve_demo_config(
        work / "config", work / "data", port, imgsz=args.imgsz, detect_fps=args.detect_fps
    )
    text = path.read_text(encoding="utf-8")
    for cam in cameras:
        pattern = rf'(name = "{cam.name}"\n)source = .*\nloop = true\n'
        detect = f'detect = "{subs[cam.name].url}"\n' if subs else ""
        text, n = re.subn(pattern, rf'\1source = "{cam.url}"\n{detect}', text)
        assert n == 1, f"camera {cam.name} not found in {path}"
    text += (
        "\n[storage]\n"
        f"segment_s = {float(args.segment_s)!r}\nmax_gb = {float(args.max_gb)!r}\n"
        "maintenance_interval_s = 30.0\n"
    )
    text = text.replace("[serve]\n", "[serve]\nstatus_interval_s = 5.0\n", 1)
    path.write_text(text, encoding="utf-8")
    return path


def get(url: str, timeout_s: float = 5.0) -> tuple[int, bytes]:
    try:
        with urllib.request.urlopen(url, timeout=timeout_s) as r:
            return r.status, r.read()
    except urllib.error.HTTPError as e:
        return e.code, e.read()
    except OSError:
        return 0, b""


def rss_mb(pid: int) -> float | None:
    """Resident memory of the process, MB (None once it has gone)."""
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    except OSError:
        return None
    return None


def folder_bytes(folder: Path) -> int:
    total = 0
    for dirpath, _, files in os.walk(folder):
        for f in files:
            with contextlib.suppress(OSError):  # deleted by retention meanwhile
                total += os.stat(os.path.join(dirpath, f)).st_size
    return total


def parse_metrics(text: str) -> dict:
    """The figures of one /metrics scrape that the soak follows."""
    m: dict = {"e2e": {}, "stages": {}, "dropped": {}, "queue_dropped": {}}
    for family in text_string_to_metric_families(text):
        for s in family.samples:
            if s.name == "stereopose_frames_total":
                m["frames"] = s.value
            elif s.name == "stereopose_frames_dropped_total":
                m["dropped"][s.labels["camera"]] = s.value
            elif s.name == "stereopose_queue_dropped_total":
                m["queue_dropped"][s.labels["queue"]] = s.value
            elif s.name == E2E + "_bucket":
                m["e2e"][s.labels["le"]] = s.value
            elif s.name in (STAGES + "_sum", STAGES + "_count"):
                key = "sum" if s.name.endswith("_sum") else "count"
                m["stages"].setdefault(s.labels["stage"], {})[key] = s.value
    return m


def quantile(q: float, buckets: dict[str, float]) -> float | None:
    """The q-quantile of a cumulative histogram {le: count}, interpolated within its bucket
    (as Prometheus' histogram_quantile); None without observations."""
    rows = sorted((float(le), c) for le, c in buckets.items())
    if not rows or rows[-1][1] <= 0:
        return None
    rank = q * rows[-1][1]
    lower, below = 0.0, 0.0
    for le, count in rows:
        if count >= rank:
            if math.isinf(le):
                return lower
            return lower + (le - lower) * (rank - below) / max(count - below, 1e-12)
        lower, below = le, count
    return lower


def diff(a: dict[str, float], b: dict[str, float]) -> dict[str, float]:
    return {k: b[k] - a.get(k, 0.0) for k in b}


def clip_files(data: Path) -> int:
    return sum(1 for _ in (data / "clips").glob("*.mp4")) if (data / "clips").is_dir() else 0


def sample(base: str, pid: int, data: Path, t0: float) -> dict:
    code, body = get(base + "/api/health")
    health = json.loads(body) if code in (200, 503) and body else None
    mcode, mbody = get(base + "/metrics")
    metrics = parse_metrics(mbody.decode()) if mcode == 200 else None
    return {
        "t_s": round(time.monotonic() - t0, 1),
        "rss_mb": rss_mb(pid),
        "health": health,
        "metrics": metrics,
        "disk_bytes": folder_bytes(data),
        "clip_files": clip_files(data),
    }


def median(xs: list[float]) -> float:
    xs = sorted(xs)
    n = len(xs)
    return xs[n // 2] if n % 2 else (xs[n // 2 - 1] + xs[n // 2]) / 2


def slope_per_hour(points: list[tuple[float, float]]) -> float | None:
    """Least-squares slope of (t seconds, value) points, per hour."""
    if len(points) < 3:
        return None
    n = len(points)
    mt = sum(t for t, _ in points) / n
    mv = sum(v for _, v in points) / n
    var = sum((t - mt) ** 2 for t, _ in points)
    if var == 0:
        return None
    return 3600 * sum((t - mt) * (v - mv) for t, v in points) / var


def summarise(samples: list[dict], warmup_s: float, cap_bytes: float) -> dict:
    """The soak's figures from its samples, over the time after the warm-up."""
    ok = [s for s in samples if s["rss_mb"] is not None and s["metrics"] is not None]
    after = [s for s in ok if s["t_s"] >= warmup_s] or ok[-1:]
    first, last = after[0], after[-1]
    span = max(last["t_s"] - first["t_s"], 1e-9)
    rss_warm = median([s["rss_mb"] for s in after[:3]])
    rss_end = median([s["rss_mb"] for s in after[-3:]])
    fm, lm = first["metrics"], last["metrics"]
    e2e = diff(fm["e2e"], lm["e2e"])
    stages = {}
    for name, v in lm["stages"].items():
        before = fm["stages"].get(name, {})
        n = v.get("count", 0) - before.get("count", 0)
        if n > 0:
            stages[name] = 1000 * (v.get("sum", 0) - before.get("sum", 0)) / n
    dropped = {c: n - fm["dropped"].get(c, 0) for c, n in lm["dropped"].items()}
    storage = [sum((s["health"] or {}).get("storage", {}).values()) for s in ok]
    statuses: dict[str, int] = {}
    for s in after:
        status = (s["health"] or {}).get("status", "no answer")
        statuses[status] = statuses.get(status, 0) + 1
    cams = (last["health"] or {}).get("cameras", {})
    # a one-time step when the first alarm clip is written (its encoder and decoder loaded)
    # is told apart from growth: the memory from the first sample with a clip on to the end
    clipped = [s for s in after if s.get("clip_files")]
    rss_clip = median([s["rss_mb"] for s in clipped[:3]]) if len(clipped) >= 6 else None
    return {
        "measured_s": round(span, 1),
        "rss_after_warmup_mb": round(rss_warm, 1),
        "rss_end_mb": round(rss_end, 1),
        "rss_growth_pct": round(100 * (rss_end - rss_warm) / rss_warm, 2),
        "rss_after_first_clip_mb": _round(rss_clip, 1),
        "rss_growth_after_first_clip_pct": (
            round(100 * (rss_end - rss_clip) / rss_clip, 2) if rss_clip else None
        ),
        "rss_slope_after_first_clip_mb_per_h": _round(
            slope_per_hour([(s["t_s"], s["rss_mb"]) for s in clipped])
        ),
        "rss_slope_mb_per_h": _round(slope_per_hour([(s["t_s"], s["rss_mb"]) for s in after])),
        "rss_max_mb": round(max(s["rss_mb"] for s in ok), 1),
        "steps_per_s": round((lm.get("frames", 0) - fm.get("frames", 0)) / span, 3),
        "latency_p50_s": _round(quantile(0.5, e2e)),
        "latency_p95_s": _round(quantile(0.95, e2e)),
        "stage_ms": {k: round(v, 2) for k, v in stages.items()},
        "dropped_frames": {c: int(n) for c, n in dropped.items()},
        "dropped_per_s": round(sum(dropped.values()) / span, 2),
        "camera_fps_end": {c: _round(v.get("fps"), 2) for c, v in cams.items()},
        "camera_reconnects_end": {c: v.get("reconnects") for c, v in cams.items()},
        "queue_dropped": lm["queue_dropped"],
        "storage_bytes_end": storage[-1] if storage else None,
        "storage_bytes_max": max(storage) if storage else None,
        "storage_cap_bytes": cap_bytes,
        "disk_bytes_end": last["disk_bytes"],
        "health_statuses": statuses,
    }


def _round(x: float | None, nd: int = 3) -> float | None:
    return None if x is None else round(x, nd)


def start_serve(python: str, config: Path, log: Path) -> subprocess.Popen:
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    with open(log, "wb") as f:
        return subprocess.Popen(
            [python, "-m", "stereopose.cli", "serve", str(config)],
            stdout=f,
            stderr=subprocess.STDOUT,
            env=env,
        )


def stop_serve(proc: subprocess.Popen, timeout_s: float = 60.0) -> tuple[int | None, float]:
    """SIGTERM, as systemd stops it; its exit code (None: killed after timeout_s) and how long
    it took."""
    t = time.monotonic()
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
    try:
        rc = proc.wait(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()
        rc = None
    return rc, time.monotonic() - t


def wait_for(predicate, what: str, timeout_s: float, proc: subprocess.Popen, log: Path) -> None:
    deadline = time.monotonic() + timeout_s
    while not predicate():
        if proc.poll() is not None:
            raise SystemExit(
                f"serve exited with {proc.returncode} while waiting for {what}:\n"
                + log.read_text(errors="replace")[-3000:]
            )
        if time.monotonic() > deadline:
            raise SystemExit(
                f"no {what} within {timeout_s:.0f} s; serve log:\n"
                + log.read_text(errors="replace")[-3000:]
            )
        time.sleep(0.5)


def soak(args) -> dict:
    work = Path(args.work).resolve()
    work.mkdir(parents=True, exist_ok=True)
    demo = pose2sim_demo_dir() / "Demo_MultiPerson" / "videos"
    videos = {n: demo / f"{n}.mp4" for n in CAMERAS}
    if not args.forward_only:
        videos = {n: palindrome(v, work / "streams" / f"{n}.mp4") for n, v in videos.items()}
    cameras = [Camera(v, n).start() for n, v in videos.items()]
    subs = {}
    if args.substreams:  # 272x480, a sixteenth of the pixels, as cameras' substreams are
        for n in videos:
            small = palindrome(demo / f"{n}.mp4", work / "streams" / f"{n}_sub.mp4", "272:480")
            subs[n] = Camera(small, f"{n}_sub").start()
    port = free_port()
    data, log = work / "data", work / "serve.log"
    if data.exists():  # a soak starts from an empty output folder (serve would resume it)
        shutil.rmtree(data)
    config = write_config(work, cameras, port, args, subs)
    base = f"http://127.0.0.1:{port}"
    proc = None
    samples: list[dict] = []
    try:
        deadline = time.monotonic() + 30
        every = [*cameras, *subs.values()]
        while not all(c.listening() for c in every) and time.monotonic() < deadline:
            time.sleep(0.2)
        proc = start_serve(args.serve_python, config, log)
        t_launch = time.monotonic()
        wait_for(lambda: get(base + "/api/health")[0] == 200, "health 200", 300, proc, log)
        startup_s = time.monotonic() - t_launch
        t0 = time.monotonic()
        print(
            f"serving on {base}, {args.duration_s:.0f} s from now; sampling every "
            f"{args.every_s:g} s",
            flush=True,
        )
        while True:
            s = sample(base, proc.pid, data, t0)
            samples.append(s)
            _progress(s)
            if proc.poll() is not None or s["t_s"] >= args.duration_s:
                break
            time.sleep(max(0.0, min(args.every_s, args.duration_s - s["t_s"])))
        died = proc.poll()
        rc, stop_s = stop_serve(proc)
    finally:
        if proc is not None and proc.poll() is None:
            stop_serve(proc, 10)
        for c in [*cameras, *subs.values()]:
            c.stop()
    text = log.read_text(errors="replace")
    summary = summarise(samples, min(args.warmup_s, args.duration_s / 4), args.max_gb * 1e9)
    summary.update(
        startup_s=round(startup_s, 1),
        exited_on_its_own=died,
        sigterm_exit_code=rc,
        sigterm_stop_s=round(stop_s, 1),
        tracebacks_in_log=text.count("Traceback"),
        camera_server_restarts={c.name: c.restarts for c in cameras},
        load_avg_end=round(os.getloadavg()[0], 2),  # other work on the machine slows serve
        calibration=calibration_events(data / "events.sqlite"),
    )
    return {"summary": summary, "samples": [compact(s) for s in samples]}


CALIBRATION_EVENTS = ("calibration_drift", "calibration_proposed", "calibration_corrected")


def calibration_events(db: Path) -> dict:
    """What the calibration keeper did to the good rig ([serve] calibration_auto, on by
    default): its events by type and camera, from the event log."""
    import sqlite3

    out: dict = {t: {} for t in CALIBRATION_EVENTS}
    if not db.exists():
        return out
    marks = ",".join("?" * len(CALIBRATION_EVENTS))
    with contextlib.closing(sqlite3.connect(f"file:{db}?mode=ro", uri=True)) as con:
        rows = con.execute(
            f"SELECT type, camera, COUNT(*) FROM events WHERE type IN ({marks}) "
            "GROUP BY type, camera",
            CALIBRATION_EVENTS,
        ).fetchall()
    for kind, camera, n in rows:
        out[kind][camera or "-"] = n
    return out


def compact(s: dict) -> dict:
    """What soak.json keeps of a sample."""
    m, h = s["metrics"] or {}, s["health"] or {}
    return {
        "t_s": s["t_s"],
        "rss_mb": _round(s["rss_mb"], 1),
        "steps": m.get("frames"),
        "status": h.get("status"),
        "dropped_frames": sum(m.get("dropped", {}).values()),
        "latency_count": max(m.get("e2e", {}).values(), default=None),
        "storage_bytes": sum(h.get("storage", {}).values()) if h else None,
        "disk_bytes": s["disk_bytes"],
        "clip_files": s.get("clip_files"),
    }


def _progress(s: dict) -> None:
    m, h = s["metrics"] or {}, s["health"] or {}
    print(
        f"  t={s['t_s']:7.1f} s  rss={s['rss_mb'] or 0:7.1f} MB  steps={m.get('frames', 0):8.0f}"
        f"  status={h.get('status', '-'):8s}  disk={s['disk_bytes'] / 1e6:8.1f} MB",
        flush=True,
    )


def report(args, result: dict) -> list[str]:
    s = result["summary"]
    mb = 1e6
    cap = f"{s['storage_cap_bytes'] / mb:.0f} MB" if s["storage_cap_bytes"] else "no cap"
    verdict = "under" if abs(s["rss_growth_pct"]) < 5 else "NOT under"
    lines = [
        "# Soak (`stereopose serve` on the real demo as 4 live HTTP cameras)",
        "",
        f"{datetime.date.today().isoformat()}, {machine().removesuffix(', one thread')}, "
        f"{_ram_gb():.0f} GB RAM. {args.duration_s:.0f} s of serve after its start-up "
        f"({s['startup_s']} s), sampled every {args.every_s:g} s, figures over the "
        f"{s['measured_s']:.0f} s after a {min(args.warmup_s, args.duration_s / 4):.0f} s "
        f"warm-up. 4 cameras of 1088x1920 at 60 fps, H.264 "
        f"{'as recorded' if args.forward_only else 'forward then backward'}, served by ffmpeg "
        f"in real time with stream copy (looped); detector ONNX at {args.imgsz}"
        + (f", detect_fps {args.detect_fps:g}" if args.detect_fps else "")
        + (
            "; each camera also serves a 272x480 substream (the same, scaled), its detect "
            "source, and its full stream is kept encoded for the clips' stream copies"
            if args.substreams
            else ""
        )
        + f"; MQTT off; storage cap {cap}, segments of {args.segment_s:g} s; serve run by "
        f"`{_where(args.serve_python)}`.",
        "",
        f"**Resident memory {s['rss_after_warmup_mb']:.0f} MB after the warm-up, "
        f"{s['rss_end_mb']:.0f} MB at the end: {s['rss_growth_pct']:+.2f} % ({verdict} 5 %).**",
        "",
        "| figure | value |",
        "|---|---|",
        f"| resident memory after warm-up / end / max | {s['rss_after_warmup_mb']} / "
        f"{s['rss_end_mb']} / {s['rss_max_mb']} MB |",
        f"| memory trend after warm-up | {_fmt(s['rss_slope_mb_per_h'])} MB per hour |",
        f"| resident memory from the first alarm clip on / growth / trend | "
        f"{_fmt(s.get('rss_after_first_clip_mb'))} MB / "
        f"{_fmt(s.get('rss_growth_after_first_clip_pct'))} % / "
        f"{_fmt(s.get('rss_slope_after_first_clip_mb_per_h'))} MB per hour |",
        f"| steps/s | {s['steps_per_s']} |",
        f"| end-to-end latency p50 / p95 | {_fmt(s['latency_p50_s'])} / "
        f"{_fmt(s['latency_p95_s'])} s |",
        f"| stages, ms per step | {', '.join(f'{k} {v}' for k, v in s['stage_ms'].items())} |",
        f"| dropped frames (all cameras) | {sum(s['dropped_frames'].values())} "
        f"({s['dropped_per_s']} per s) |",
        f"| camera fps at the end | {_pairs(s['camera_fps_end'])} |",
        f"| camera reconnects | {_pairs(s['camera_reconnects_end'])} |",
        f"| storage used (end / max) against the cap | {_mb(s['storage_bytes_end'])} / "
        f"{_mb(s['storage_bytes_max'])} of {cap} (output folder {_mb(s['disk_bytes_end'])}) |",
        f"| health over the samples | {_pairs(s['health_statuses'])} |",
        f"| SIGTERM | exit code {s['sigterm_exit_code']} after {s['sigterm_stop_s']} s |",
        f"| tracebacks in the log | {s['tracebacks_in_log']} |",
        f"| camera servers restarted | {_pairs(s['camera_server_restarts'])} |",
        f"| machine load (1 min) at the end | {s.get('load_avg_end', '-')} |",
        "| the calibration keeper (calibration_auto on): drift / proposed / corrected | "
        + " / ".join(
            _pairs(s.get("calibration", {}).get(k, {})) or "none" for k in CALIBRATION_EVENTS
        )
        + " |",
        "",
        *(
            [
                f"A short check run ({args.duration_s:.0f} s): `make soak` runs the full 30 "
                "minutes.",
                "",
            ]
            if args.duration_s < 1800
            else []
        ),
        "Steps: the frame loop's time steps (one detection of the 4 cameras' newest frames "
        "each); latency: from a step's frames' arrival to the end of its outputs, from the "
        "`stereopose_end_to_end_latency_seconds` histogram (interpolated within its buckets); "
        "dropped frames: frames each camera received but no step used; camera servers "
        "restarted: ffmpeg serves one connection, so each time serve opens a stream the "
        "server is started anew (serve's own reconnects are counted apart). The samples are in "
        f"{args.name}.json.",
        "",
        "| t (s) | resident MB | steps | status | output folder MB |",
        "|---|---|---|---|---|",
    ]
    samples = result["samples"]
    stride = max(1, len(samples) // 12)
    for x in samples[::stride] + ([samples[-1]] if (len(samples) - 1) % stride else []):
        lines.append(
            f"| {x['t_s']:.0f} | {_fmt(x['rss_mb'], 1)} | {x['steps'] or 0:.0f} | "
            f"{x['status'] or '-'} | {x['disk_bytes'] / mb:.1f} |"
        )
    return lines


def _where(python: str) -> str:
    """The interpreter's path relative to the repository where it is inside it."""
    path = Path(python).absolute()
    return str(path.relative_to(ROOT)) if path.is_relative_to(ROOT) else str(path)


def _fmt(x: float | None, nd: int = 3) -> str:
    return "-" if x is None else f"{x:.{nd}f}"


def _mb(x: float | None) -> str:
    return "-" if x is None else f"{x / 1e6:.1f} MB"


def _pairs(d: dict) -> str:
    return ", ".join(f"{k} {v}" for k, v in d.items()) or "-"


def _ram_gb() -> float:
    for line in Path("/proc/meminfo").read_text().splitlines():
        if line.startswith("MemTotal:"):
            return int(line.split()[1]) / 2**20
    return 0.0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration-s", type=float, default=1800.0, help="serve this long (1800)")
    ap.add_argument("--every-s", type=float, default=10.0, help="sample this often (10)")
    ap.add_argument(
        "--warmup-s",
        type=float,
        default=120.0,
        help="left out of the figures (120; at most a quarter of the duration)",
    )
    ap.add_argument("--imgsz", type=int, default=640, help="detector input size (640)")
    ap.add_argument("--detect-fps", type=float, help="[input] detect_fps (default: none)")
    ap.add_argument(
        "--substreams",
        action="store_true",
        help="each camera also serves a 272x480 substream, its detect source",
    )
    ap.add_argument("--max-gb", type=float, default=1.0, help="[storage] max_gb (1)")
    ap.add_argument("--segment-s", type=float, default=300.0, help="[storage] segment_s (300)")
    ap.add_argument(
        "--forward-only",
        action="store_true",
        help="serve the videos as recorded (people jump where they loop)",
    )
    ap.add_argument(
        "--serve-python",
        default=sys.executable,
        help="the Python that runs serve, e.g. .venv-runtime/bin/python (this one)",
    )
    ap.add_argument("--work", default=str(ROOT / "out" / "soak"), help="working folder")
    ap.add_argument("--name", default="soak", help="results/<name>.{md,json} (soak)")
    args = ap.parse_args()
    if args.duration_s < 30 or args.every_s <= 0:
        ap.error("--duration-s must be at least 30 and --every-s positive")
    result = soak(args)
    result["args"] = vars(args)
    result["machine"] = machine().removesuffix(", one thread")
    result["date"] = datetime.date.today().isoformat()
    save(args.name, result, report(args, result))
    s = result["summary"]
    print(
        f"memory {s['rss_after_warmup_mb']} -> {s['rss_end_mb']} MB "
        f"({s['rss_growth_pct']:+.2f} %), {s['steps_per_s']} steps/s, latency p50 "
        f"{_fmt(s['latency_p50_s'])} s p95 {_fmt(s['latency_p95_s'])} s, SIGTERM exit "
        f"{s['sigterm_exit_code']}"
    )


if __name__ == "__main__":
    main()
