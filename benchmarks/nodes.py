"""Detection over nodes against one process: the real demo's cameras looped, 4, 8 and 16 of them.

For each number of cameras N (the demo's four cameras repeated under new names, each copy with
its original's calibration and video) three set-ups run as real processes on this machine,
with a real mosquitto:

- `single`: today's `stereopose serve`, the cameras opened and detected in its own process;
- `1 node`: one `stereopose detect-node` with all N cameras and the fusion `serve`
  ([input] detection = "nodes");
- `2 nodes`: two nodes with N/2 cameras each (one inference thread each) and the fusion serve.

Once every camera is up and the loop warm, each set-up is measured for --seconds: steps per
second (detected steps given to the loop: status.json's pipeline `delivered`, or the nodes'
`steps`; the service's empty heartbeat steps are not counted), the latency of each step
(nodes: from capture to its `people` message on the broker, received wall time - (the run's
wall_start + the step's t), and to its zone events; a heartbeat step, off the detect_fps grid,
left out; single: the pipeline's own figure, from the frames' read to the end of the loop's
work, as its heartbeats move a slow step's t), the broker's bytes per second on the node
topics (keypoints, pictures, health), what was dropped (the nodes' queues, late / over-full /
refused camera-frames, steps given without every camera; single: detection steps dropped at
the hand-over) and each process's CPU.
The nodes run on the wall-clock grid of detect_fps = the single process's measured rate for
that N (the largest of GRID at or under it), so that they can keep up.

Then, from the measured per-camera costs (bytes per camera-frame, the fusion's CPU per step
and camera), a table on paper for 64 cameras at 25 fps on 4 GPU nodes.

Results in results/nodes.{json,md}. The machine is shared by every process: on one machine two
nodes cannot add capacity, only show what the split costs.
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import json
import os
import shutil
import signal
import socket
import sqlite3
import statistics
import subprocess
import sys
import tempfile
import time
import urllib.request
from importlib import resources
from pathlib import Path

import numpy as np
import paho.mqtt.client as paho
import psutil

from common import machine, save
from stereopose.calibration.formats import load_calibration, save_calibration
from stereopose.detection.models import demo_videos
from stereopose.types import Rig

GRID = (0.5, 1.0, 1.5, 2.0, 2.5, 3.0, 4.0, 5.0, 6.0, 8.0, 10.0, 12.5, 15.0, 20.0, 25.0)
SITE = "bench"


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def write_setup(
    folder: Path, n: int, mode: str, broker: int, http: int, grid: float | None, imgsz: int
) -> Path:
    """The rig of n cameras, the demo site and the service's configuration in `folder`."""
    folder.mkdir(parents=True, exist_ok=True)
    videos = demo_videos()
    calib = sorted(Path(videos[0]).parents[1].glob("calibration/Calib.qca.txt"))[0]
    demo = load_calibration(calib)
    cams = [dataclasses.replace(demo[i % 4], name=f"c{i + 1:02d}") for i in range(n)]
    save_calibration(folder / "calib.toml", Rig(cams))
    site = resources.files("stereopose") / "data" / "demo_site.toml"
    (folder / "site.toml").write_text(site.read_text(encoding="utf-8"))
    lines = [
        'calibration = "calib.toml"',
        'site = "site.toml"',
        'output = "data"',
        "",
        "[detector]",
        f"imgsz = {imgsz}",
        "",
        "[input]",
    ]
    if mode != "single":
        lines.append('detection = "nodes"')
    if grid is not None and mode != "single":
        lines.append(f"detect_fps = {grid}")
    # a camera's frames come a step period and a node's detection late: at 16 cameras on this
    # machine over 4 s, more than serve's default timeout of 5 s
    lines += [
        "",
        "[serve]",
        f"port = {http}",
        "status_interval_s = 1",
        "camera_timeout_s = 15",
        "",
        "[mqtt]",
        'host = "127.0.0.1"',
        f"port = {broker}",
        f'site = "{SITE}"',
        "people_hz = 1000",
        "outbox = false",
        "",
        "[storage]",
        "clips = false",
        "",
    ]
    for i in range(n):
        lines += [
            "[[cameras]]",
            f'name = "c{i + 1:02d}"',
            f'source = "{videos[i % 4]}"',
            "loop = true",
            "",
        ]
    path = folder / "serve.toml"
    path.write_text("\n".join(lines))
    return path


class Listener:
    """The broker's side: bytes on the node topics, the people updates' and events' latency."""

    def __init__(self, port: int, wall_start, grid: float | None) -> None:
        self.wall_start = wall_start  # () -> the run's wall_start, or None while not known
        # nodes: a step's t is a capture time on the detect_fps grid; an empty step (the
        # service's heartbeat, repeating the last people) is off it and left out
        self.grid = grid
        self.bytes = {"keypoints": 0, "pictures": 0, "nodes": 0}
        self.people: list[float] = []
        self.events: list[float] = []
        self.measuring = False
        self.client = paho.Client(paho.CallbackAPIVersion.VERSION2, protocol=paho.MQTTv311)
        self.client.on_connect = lambda c, *_: c.subscribe(f"stereopose/{SITE}/#", 0)
        self.client.on_message = self._on
        self.client.connect("127.0.0.1", port)
        self.client.loop_start()

    def _on(self, client, userdata, msg) -> None:
        if not self.measuring:
            return
        now = time.time()
        kind = msg.topic.split("/")[2]
        if kind in self.bytes:
            self.bytes[kind] += len(msg.payload)
            return
        start = self.wall_start()
        if start is None or kind not in ("people", "events"):
            return
        doc = json.loads(msg.payload)
        if self.grid is None:
            return  # one process: its steps' own latency is the pipeline's (status.json)
        ticks = (start + doc["t"]) * self.grid
        if abs(ticks - round(ticks)) > 1e-3:
            return
        if kind == "people":
            self.people.append(now - (start + doc["t"]))
        elif doc.get("kind") == "energized":
            self.events.append(now - (start + doc["t"]))

    def close(self) -> None:
        self.client.disconnect()
        self.client.loop_stop()


def health(port: int) -> dict:
    try:
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/api/health", timeout=5) as r:
            return json.loads(r.read())
    except OSError:
        return {}


def wall_start(db: Path) -> float | None:
    if not db.exists():
        return None
    try:
        con = sqlite3.connect(f"file:{db}?mode=ro", uri=True, timeout=2)
        try:
            row = con.execute("SELECT wall_start FROM runs ORDER BY id DESC LIMIT 1").fetchone()
        finally:
            con.close()
    except sqlite3.Error:
        return None
    return None if row is None else row[0]


def status(folder: Path) -> dict:
    try:
        return json.loads((folder / "data" / "status.json").read_text())
    except (OSError, ValueError):
        return {}


def cpu(procs: dict[str, psutil.Process]) -> dict[str, float]:
    out = {}
    for name, p in procs.items():
        try:
            t = p.cpu_times()
            out[name] = t.user + t.system
        except psutil.Error:
            out[name] = float("nan")
    return out


def q(values: list[float], p: float) -> float | None:
    return round(float(np.quantile(values, p)), 3) if values else None


def stop_all(procs: dict[str, subprocess.Popen], logs: list, tmp: Path) -> None:
    """The set-up's processes stopped (SIGTERM, then killed after 30 s), last started first;
    their logs closed and its folder removed."""
    for p in reversed(list(procs.values())):
        if p.poll() is None:
            p.send_signal(signal.SIGTERM)
            try:
                p.wait(30)
            except subprocess.TimeoutExpired:
                p.kill()
    for log in logs:
        log.close()
    shutil.rmtree(tmp, ignore_errors=True)


def run_setup(
    n: int, mode: str, grid: float | None, seconds: float, imgsz: int, mosquitto: str
) -> dict:
    tmp = Path(tempfile.mkdtemp(prefix=f"nodes-{n}-{mode.replace(' ', '')}-"))
    broker_port, http = free_port(), free_port()
    (tmp / "mosquitto.conf").write_text(
        f"listener {broker_port} 127.0.0.1\nallow_anonymous true\npersistence false\n"
    )
    config = write_setup(tmp, n, mode, broker_port, http, grid, imgsz)
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    procs: dict[str, subprocess.Popen] = {}
    logs = []

    def start(name: str, args: list[str], extra: dict | None = None) -> None:
        log = open(tmp / f"{name}.log", "wb")  # noqa: SIM115  # closed at the end
        logs.append(log)
        procs[name] = subprocess.Popen(
            args, stdout=log, stderr=subprocess.STDOUT, env={**env, **(extra or {})}
        )

    cli = [sys.executable, "-m", "stereopose.cli"]
    start("mosquitto", [mosquitto, "-c", str(tmp / "mosquitto.conf")])
    time.sleep(0.5)
    start("serve", [*cli, "serve", str(config)])
    names = [f"c{i + 1:02d}" for i in range(n)]
    if mode == "1 node":
        start(
            "node-1",
            [*cli, "detect-node", str(config), "--cameras", ",".join(names), "--name", "node-1"],
        )
    elif mode == "2 nodes":
        for k, part in enumerate((names[: n // 2], names[n // 2 :]), 1):
            start(
                f"node-{k}",
                [
                    *cli,
                    "detect-node",
                    str(config),
                    "--cameras",
                    ",".join(part),
                    "--name",
                    f"node-{k}",
                ],
                {"STEREOPOSE_THREADS": "1"},
            )
    listener = None
    try:
        deadline = time.monotonic() + 300
        while time.monotonic() < deadline:
            h = health(http)
            cams = h.get("cameras", {})
            if len(cams) == n and all(c["state"] == "up" for c in cams.values()):
                break
            for name, p in procs.items():
                if p.poll() is not None:
                    raise RuntimeError(f"{name} ended: {(tmp / f'{name}.log').read_text()[-2000:]}")
            time.sleep(1)
        else:
            raise RuntimeError(f"{n} {mode}: the cameras did not come up")
        time.sleep(15)  # warm: the 3D stage compiled, the nodes' queues settled
        db = tmp / "data" / "events.sqlite"
        listener = Listener(broker_port, lambda: wall_start(db), None if mode == "single" else grid)
        ps = {k: psutil.Process(p.pid) for k, p in procs.items() if k != "mosquitto"}
        ps["mosquitto"] = psutil.Process(procs["mosquitto"].pid)
        s0, c0, t0 = status(tmp), cpu(ps), time.monotonic()
        listener.measuring = True
        time.sleep(seconds)
        listener.measuring = False
        s1, h1, c1, t1 = status(tmp), health(http), cpu(ps), time.monotonic()
        span = t1 - t0
        if mode == "single":  # the steps detected and given to the loop (no empty step)
            steps = s1["pipeline"]["delivered"] - s0["pipeline"]["delivered"]
        else:
            steps = s1["nodes"]["steps"] - s0["nodes"]["steps"]
        out = {
            "cameras": n,
            "mode": mode,
            "detect_fps": grid if mode != "single" else None,
            "seconds": round(span, 1),
            "steps": steps,
            "steps_per_s": round(steps / span, 2),
            "people_latency_p50_s": q(listener.people, 0.5),
            "people_latency_p95_s": q(listener.people, 0.95),
            "people_updates": len(listener.people),
            "event_latency_p50_s": q(listener.events, 0.5),
            "event_latency_p95_s": q(listener.events, 0.95),
            "events": len(listener.events),
            "broker_bytes_per_s": {k: round(v / span) for k, v in listener.bytes.items()},
            "cpu_cores": {k: round((c1[k] - c0[k]) / span, 2) for k in c0},
            "people_mean": h1.get("people"),
        }
        if mode == "single":
            p0, p1 = s0.get("pipeline", {}), s1.get("pipeline", {})
            out["dropped_steps"] = p1.get("dropped", 0) - p0.get("dropped", 0)
            out["pipeline_latency_p50_s"] = p1.get("latency_p50_s")  # read -> loop done
            out["pipeline_latency_p95_s"] = p1.get("latency_p95_s")
        else:
            r0, r1 = s0.get("nodes", {}), s1.get("nodes", {})
            lost = {}
            for key in ("late", "dropped", "refused"):
                lost[key] = sum(c[key] for c in r1["cameras"].values()) - sum(
                    c[key] for c in r0["cameras"].values()
                )
            frames = sum(c["frames"] for c in r1["cameras"].values()) - sum(
                c["frames"] for c in r0["cameras"].values()
            )
            kp_bytes = sum(c["bytes"] for c in r1["cameras"].values()) - sum(
                c["bytes"] for c in r0["cameras"].values()
            )
            out["camera_frames"] = frames
            out["bytes_per_camera_frame"] = round(kp_bytes / frames) if frames else None
            out["lost_camera_frames"] = lost
            out["partial_steps"] = r1.get("partial_steps", 0) - r0.get("partial_steps", 0)
            out["node_queue_dropped"] = sum(
                (v.get("queue") or {}).get("dropped", 0) for v in r1.get("nodes", {}).values()
            )
            skipped = {}
            for name, v in r1.get("nodes", {}).items():
                skipped[name] = sum(c.get("dropped", 0) for c in (v.get("cameras") or {}).values())
            out["grid_times_passed_over"] = skipped
        return out
    finally:
        if listener is not None:
            listener.close()
        stop_all(procs, logs, tmp)


def events(r: dict) -> str:
    if r["mode"] == "single" or not r["events"]:
        return "-"
    return f"{r['event_latency_p50_s']} / {r['event_latency_p95_s']} ({r['events']})"


def latency(r: dict) -> str:
    if r["mode"] == "single":
        return f"{r['pipeline_latency_p50_s']:.3f} / {r['pipeline_latency_p95_s']:.3f} (read)"
    return f"{r['people_latency_p50_s']} / {r['people_latency_p95_s']}"


def paper(results: list[dict]) -> list[str]:
    """64 cameras at 25 fps on 4 GPU nodes, from the measured per-camera costs."""
    nodes = [r for r in results if r["mode"] != "single" and r.get("bytes_per_camera_frame")]
    if not nodes:
        return []
    per_frame = statistics.median(r["bytes_per_camera_frame"] for r in nodes)
    kp = 64 * 25 * per_frame
    pic = 64 * statistics.median(r["broker_bytes_per_s"]["pictures"] / r["cameras"] for r in nodes)
    serve = [r["cpu_cores"]["serve"] for r in nodes]
    return [
        "",
        "## On paper: 64 cameras at 25 fps on 4 GPU nodes",
        "",
        "From the figures above; no GPU was measured (benchmarks/gpu.py gives the GPU side when "
        "one is lent):",
        "",
        "| | per node (16 cameras) | whole site (64 cameras) |",
        "|---|---|---|",
        "| camera-frames per second | 400 | 1,600 |",
        f"| keypoints to the broker (median {per_frame:.0f} B a camera-frame, the demo's 3 "
        f"people) | {16 * 25 * per_frame / 1e3:.0f} kB/s | {kp / 1e6:.2f} MB/s "
        f"({kp * 8 / 1e6:.1f} Mbit/s) |",
        f"| pictures (1 Hz, 1/4 size) | {pic / 4 / 1e3:.0f} kB/s | {pic / 1e3:.0f} kB/s |",
        "| GPU detection needed | 400 frames/s: at most 2.5 ms a frame at batch 16 | 4 GPUs |",
        f"| fusion service | | measured here {min(serve):.2f} to {max(serve):.2f} of a core at "
        "4 to 16 cameras and these rates, most of it fixed (console, health, status); the 3D "
        "stage: 6 cameras x 5 people at 170 steps/s on one core (reconstruct_process.md), "
        "about 6 ms a step |",
        "",
        "The broker's load is small: a 1 Gbit/s site network carries 64 cameras' keypoints "
        "and pictures fifty times over. The fusion's cost at 64 cameras and 25 steps/s is "
        "not measured: the 3D stage's cost grows with the cameras (linearly in the views, and "
        "with the camera pairs in the association), so it lies between about 1.6 cores "
        "(64 ms a step, linear) and a few times that; measuring it takes nodes publishing "
        "recorded keypoints at that rate, which this machine cannot detect.",
    ]


def report(head: dict, results: list[dict]) -> None:
    """results/nodes.{json,md}."""
    md = [
        "# Detection over nodes against one process",
        "",
        f"`python benchmarks/nodes.py`, {head['date']}, "
        f"{head['machine'].replace(', one thread', '')}; "
        "every process (mosquitto, serve, the nodes) on this one machine; "
        f"imgsz {head['imgsz']}, "
        f"{head['seconds']:.0f} s measured per set-up after warming; load average "
        f"{head['load_average'][0]} at the start, {head['load_average'][1]} at the end. The "
        "demo's 4 cameras repeated to 8 and 16 (same videos, same calibration per copy). "
        "The nodes detect on the wall clock's grid of detect_fps, the largest of "
        f"{', '.join(f'{g:g}' for g in GRID)} at or under the single process's rate for "
        "the same cameras. Latency: nodes, from capture to the step's people on the broker "
        "and to its zone events; single, the pipeline's own, from the frames' read to the "
        "end of the loop's work.",
        "",
        "| cameras | set-up | detect_fps | steps/s | capture -> people p50 / p95 s | "
        "-> zone event p50 / p95 s | broker B/s (keypoints + pictures + health) | "
        "B a camera-frame | lost (late / over-full / refused), partial steps | CPU cores "
        "(serve / nodes / mosquitto) |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in sorted(results, key=lambda r: (r["cameras"], r["mode"] != "single", r["mode"])):
        b = r["broker_bytes_per_s"]
        cores = r["cpu_cores"]
        nodes = sum(v for k, v in cores.items() if k.startswith("node"))
        if r["mode"] == "single":
            lost = f"{r['dropped_steps']} steps dropped"
        else:
            lc = r["lost_camera_frames"]
            lost = f"{lc['late']} / {lc['dropped']} / {lc['refused']}, {r['partial_steps']}"
        md.append(
            f"| {r['cameras']} | {r['mode']} | {r['detect_fps'] or '-'} | {r['steps_per_s']} | "
            f"{latency(r)} | {events(r)} | {sum(b.values()):,} | "
            f"{r.get('bytes_per_camera_frame') or '-'} | {lost} | "
            f"{cores['serve']} / {nodes:.2f} / {cores['mosquitto']} |"
        )
    md += paper(results)
    save("nodes", {**head, "results": results}, md)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cameras", default="4,8,16")
    ap.add_argument("--seconds", type=float, default=40.0)
    ap.add_argument("--imgsz", type=int, default=640)
    ap.add_argument("--modes", default="single,1 node,2 nodes")
    ap.add_argument(
        "--previous",
        type=Path,
        help="results of earlier set-ups (this script's JSON lines) to keep",
    )
    ap.add_argument(
        "--grid",
        type=float,
        help="the nodes' detect_fps (default: the single process's rate for the same cameras)",
    )
    args = ap.parse_args()
    mosquitto = shutil.which("mosquitto", path=os.pathsep.join([os.environ["PATH"], "/usr/sbin"]))
    if mosquitto is None or not demo_videos():
        sys.exit("needs mosquitto (Debian package) and the demo videos (make install)")
    results, load0 = [], os.getloadavg()[0]
    if args.previous is not None:
        for line in args.previous.read_text().splitlines():
            if line.startswith("{"):
                results.append(json.loads(line))
                print(line, flush=True)
    for n in (int(x) for x in args.cameras.split(",")):
        grid = args.grid or next(
            (
                max([g for g in GRID if g <= r["steps_per_s"]] or [GRID[0]])
                for r in results
                if r["cameras"] == n and r["mode"] == "single"
            ),
            None,
        )
        for mode in args.modes.split(","):
            r = run_setup(n, mode, grid, args.seconds, args.imgsz, mosquitto)
            if mode == "single":
                grid = max([g for g in GRID if g <= r["steps_per_s"]] or [GRID[0]])
            print(json.dumps(r), flush=True)
            results.append(r)
    head = {
        "date": datetime.date.today().isoformat(),
        "machine": machine(),
        "imgsz": args.imgsz,
        "seconds": args.seconds,
        "load_average": [round(load0, 2), round(os.getloadavg()[0], 2)],
    }
    report(head, results)


if __name__ == "__main__":
    main()
