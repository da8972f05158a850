"""The fusion service at 16, 32 and 64 cameras, up to 25 steps/s: recorded 2D people replayed
through the nodes' wire into a real `stereopose serve`.

The people: the real demo's four cameras detected once here (YOLO11n-pose, ONNX Runtime, every
frame of the recording), then repeated under new names as benchmarks/nodes.py does: camera k
is the demo's camera k mod 4, with its calibration and its detections, so at N cameras every
camera sees the demo's people (the association's worst case: every pair of the N(N-1)/2 sees
the same people). A replayer in this process plays the nodes: on the wall clock's grid of
`rate` steps/s it publishes every camera's keypoints message of that grid time (capture time
= the grid time, sent DETECT_S after it, as a GPU node's detection would), split over NODES
nodes, each with its health every second and each camera's picture (a quarter-size JPEG of
the demo's frame) once a second, as real nodes send.

Measured over --seconds after the service settled: the steps/s held (status.json's nodes
steps), each process's CPU (serve, mosquitto, the replayer), the latency from capture to the
step's people on the broker and to its zone events, what was lost (camera-frames late,
over-full, refused, flooded; steps given without every camera; the loop's own drops), and each
stage's mean time a step from /metrics. Then the 3D stage alone, in this process on one
thread with the same people and rigs (`Stage3D.step`, profiled): its ms a step and the share
of its largest parts, so that the part that limits the service is named.
Results in results/fusion_scale.{json,md}; --previous keeps the set-ups of an earlier run (its
JSON lines) and measures the rest.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import threading
import time
import urllib.error
import urllib.request
from pathlib import Path

import cv2
import paho.mqtt.client as paho
import psutil

from common import machine, save
from nodes import (
    SITE,
    Listener,
    cpu,
    free_port,
    q,
    status,
    stop_all,
    wall_start,
    write_setup,
)
from stereopose.detection.models import demo_videos
from stereopose.nodes.wire import Topics, encode_people, encode_picture, health_message
from stereopose.types import People2D

NODES = 4  # the site's detection nodes (a GPU each)
DETECT_S = 0.02  # a camera-frame's detection at its node: sent this long after capture
PICTURE_EVERY_S = 1.0
SIZE = (1920.0, 1088.0)  # the demo cameras' calibrated size


def record(frames: int) -> tuple[list[list[People2D]], list[bytes]]:
    """The demo's 4 cameras detected, every frame (at most `frames`): per camera its people
    per frame, and a quarter-size JPEG of its first frame."""
    from stereopose.detection import make_detector

    det = make_detector("onnx")
    people, pictures = [], []
    for c, video in enumerate(demo_videos()[:4]):
        cap = cv2.VideoCapture(str(video), cv2.CAP_FFMPEG)
        mine = []
        while len(mine) < frames:
            ok, im = cap.read()
            if not ok:
                break
            if not mine:
                small = cv2.resize(im, (im.shape[1] // 4, im.shape[0] // 4))
                pictures.append(cv2.imencode(".jpg", small)[1].tobytes())
            mine.append(det.detect([im])[0].people(f"cam{c + 1:02d}", len(mine)))
        cap.release()
        people.append(mine)
    return people, pictures


class Replayer:
    """NODES nodes' worth of keypoints, health and pictures on the broker (see the module)."""

    def __init__(
        self, port: int, n: int, rate: float, people: list[list[People2D]], pictures: list[bytes]
    ) -> None:
        self.n, self.rate, self.people, self.pictures = n, rate, people, pictures
        self.names = [f"c{i + 1:02d}" for i in range(n)]
        self.node_of = {name: f"node-{i * NODES // n + 1}" for i, name in enumerate(self.names)}
        self.topics = Topics.of("stereopose", SITE)
        self.sent = 0
        self.behind = 0  # grid times the replayer itself was late for (sent late, counted)
        self._stop = threading.Event()
        self.client = paho.Client(
            paho.CallbackAPIVersion.VERSION2,
            protocol=paho.MQTTv311,
            client_id=f"replayer-{os.getpid()}",
        )
        self.client.max_queued_messages_set(0)
        self.client.connect("127.0.0.1", port)
        self.client.loop_start()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _health(self, frames: int) -> None:
        for node in sorted(set(self.node_of.values())):
            cams = {
                c: {
                    "fps": 25.0,
                    "detect_fps": self.rate,
                    "frames": frames,
                    "dropped": 0,
                    "up": True,
                }
                for c, nd in self.node_of.items()
                if nd == node
            }
            body = health_message(
                node,
                "online",
                clock=time.time(),
                cameras=cams,
                detect_ms=2.0,
                queue={"queued": 0, "dropped": 0},
                backend="replay",
            )
            self.client.publish(self.topics.node(node), body, qos=1, retain=True)

    def _run(self) -> None:
        period = 1.0 / self.rate
        k = int(time.time() / period) + 1
        next_health = next_picture = 0.0
        while not self._stop.is_set():
            t = k * period
            wait = t + DETECT_S - time.time()
            if wait > 0:
                self._stop.wait(wait)
            elif wait < -period:
                self.behind += 1
            now = time.time()
            if now >= next_health:
                self._health(k)
                next_health = now + 1.0
            frame = k % len(self.people[0])
            for i, name in enumerate(self.names):
                p = self.people[i % 4][frame % len(self.people[i % 4])]
                p = People2D(name, k, p.keypoints, p.boxes, p.scores)
                payload = encode_people(self.node_of[name], p, t, SIZE)
                self.client.publish(self.topics.keypoints(name), payload, qos=0)
                self.sent += 1
            if now >= next_picture:
                for i, name in enumerate(self.names):
                    self.client.publish(
                        self.topics.picture(name), encode_picture(t, self.pictures[i % 4]), qos=0
                    )
                next_picture = now + PICTURE_EVERY_S
            k = max(k + 1, int(time.time() / period))  # a grid time passed over: as a node

    def close(self) -> None:
        self._stop.set()
        self.thread.join(5)
        for node in sorted(set(self.node_of.values())):
            self.client.publish(
                self.topics.node(node), health_message(node, "offline"), qos=1, retain=True
            ).wait_for_publish(5)
        self.client.disconnect()
        self.client.loop_stop()


def health(port: int) -> dict:
    """/api/health, also when it says degraded (503), as it does until the cameras are up."""
    try:
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/api/health", timeout=5) as r:
            return json.loads(r.read())
    except urllib.error.HTTPError as e:
        try:
            return json.loads(e.read())
        except ValueError:
            return {}
    except (OSError, ValueError):
        return {}


def stages(port: int) -> dict[str, tuple[float, float]]:
    """/metrics: each stage's (seconds, steps) so far."""
    try:
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/metrics", timeout=5) as r:
            text = r.read().decode()
    except OSError:
        return {}
    out: dict[str, list[float]] = {}
    for m in re.finditer(
        r'^stereopose_stage_seconds_(sum|count)\{stage="([^"]+)"\} (\S+)$', text, re.M
    ):
        out.setdefault(m[2], [0.0, 0.0])[0 if m[1] == "sum" else 1] = float(m[3])
    return {k: (v[0], v[1]) for k, v in out.items()}


def run_setup(n: int, rate: float, seconds: float, people, pictures, mosquitto: str) -> dict:
    tmp = Path(tempfile.mkdtemp(prefix=f"fusion-{n}-{rate:g}-"))
    broker_port, http = free_port(), free_port()
    (tmp / "mosquitto.conf").write_text(
        f"listener {broker_port} 127.0.0.1\n"
        "allow_anonymous true\npersistence false\n"
        "max_queued_messages 100000\n"
    )
    config = write_setup(tmp, n, "nodes", broker_port, http, rate, 640)
    procs: dict[str, subprocess.Popen] = {}
    logs = []

    def start(name: str, args: list[str]) -> None:
        log = open(tmp / f"{name}.log", "wb")  # noqa: SIM115  # closed at the end
        logs.append(log)
        procs[name] = subprocess.Popen(
            args, stdout=log, stderr=subprocess.STDOUT, env=dict(os.environ, PYTHONUNBUFFERED="1")
        )

    start("mosquitto", [mosquitto, "-c", str(tmp / "mosquitto.conf")])
    time.sleep(0.5)
    start("serve", [sys.executable, "-m", "stereopose.cli", "serve", str(config)])
    replayer = listener = None
    try:
        deadline = time.monotonic() + 300
        while not health(http) and time.monotonic() < deadline:
            if procs["serve"].poll() is not None:
                raise RuntimeError((tmp / "serve.log").read_text()[-2000:])
            time.sleep(0.5)
        replayer = Replayer(broker_port, n, rate, people, pictures)
        while time.monotonic() < deadline:
            cams = health(http).get("cameras", {})
            if len(cams) == n and all(c["state"] == "up" for c in cams.values()):
                break
            if procs["serve"].poll() is not None:
                raise RuntimeError((tmp / "serve.log").read_text()[-2000:])
            time.sleep(1)
        else:
            raise RuntimeError(f"{n} cameras at {rate}: the cameras did not come up")
        time.sleep(10)  # warm: the 3D stage compiled, the queues settled
        db = tmp / "data" / "events.sqlite"
        listener = Listener(broker_port, lambda: wall_start(db), rate)
        ps = {k: psutil.Process(p.pid) for k, p in procs.items()}
        ps["replayer"] = psutil.Process()
        s0, c0, g0, t0 = status(tmp), cpu(ps), stages(http), time.monotonic()
        sent0 = replayer.sent
        listener.measuring = True
        time.sleep(seconds)
        listener.measuring = False
        s1, c1, g1, t1 = status(tmp), cpu(ps), stages(http), time.monotonic()
        span = t1 - t0
        r0, r1 = s0.get("nodes", {}), s1.get("nodes", {})
        steps = r1["steps"] - r0["steps"]

        def delta(key: str) -> int:
            return sum(c.get(key, 0) for c in r1["cameras"].values()) - sum(
                c.get(key, 0) for c in r0["cameras"].values()
            )

        per_stage = {
            k: round(
                1000 * (v[0] - g0.get(k, (0, 0))[0]) / max(1.0, v[1] - g0.get(k, (0, 0))[1]), 2
            )
            for k, v in g1.items()
        }
        p0, p1 = s0.get("pipeline", {}), s1.get("pipeline", {})
        return {
            "cameras": n,
            "camera_pairs": n * (n - 1) // 2,
            "rate": rate,
            "seconds": round(span, 1),
            "steps": steps,
            "steps_per_s": round(steps / span, 2),
            "held": steps / span >= 0.95 * rate,
            "camera_frames_sent": replayer.sent - sent0,
            "camera_frames_used": delta("used"),
            "lost": {k: delta(k) for k in ("late", "dropped", "refused", "flood")},
            "partial_steps": r1.get("partial_steps", 0) - r0.get("partial_steps", 0),
            "loop_dropped": p1.get("dropped", 0) - p0.get("dropped", 0),
            "replayer_behind": replayer.behind,
            "people_latency_p50_s": q(listener.people, 0.5),
            "people_latency_p95_s": q(listener.people, 0.95),
            "people_updates": len(listener.people),
            "event_latency_p50_s": q(listener.events, 0.5),
            "event_latency_p95_s": q(listener.events, 0.95),
            "events": len(listener.events),
            "cpu_cores": {k: round((c1[k] - c0[k]) / span, 2) for k in c0},
            "stage_ms": per_stage,
            "people_mean": health(http).get("people"),
        }
    finally:
        if listener is not None:
            listener.close()
        if replayer is not None:
            replayer.close()
        stop_all(procs, logs, tmp)


def stage_alone(n: int, people: list[list[People2D]], steps: int = 20) -> dict:
    """The 3D stage alone at n cameras (the demo's repeated): ms a step, and the parts that
    take the most of it (cProfile's cumulative time of the stereopose functions)."""
    import cProfile
    import dataclasses
    import pstats

    from stereopose.calibration.formats import load_calibration
    from stereopose.pipeline.stage3d import Stage3D
    from stereopose.types import Rig

    calib = sorted(Path(demo_videos()[0]).parents[1].glob("calibration/Calib.qca.txt"))[0]
    demo = load_calibration(calib)
    rig = Rig([dataclasses.replace(demo[i % 4], name=f"c{i + 1:02d}") for i in range(n)])
    stage = Stage3D(rig)
    stage.load()

    def step(k: int) -> None:
        views = {}
        for i in range(n):
            p = people[i % 4][k % len(people[i % 4])]
            views[f"c{i + 1:02d}"] = People2D(f"c{i + 1:02d}", k, p.keypoints, p.boxes, p.scores)
        stage.step(k, views, k / 25)

    for k in range(3):  # warm
        step(k)
    prof = cProfile.Profile()
    t0 = time.perf_counter()
    prof.enable()
    for k in range(3, 3 + steps):
        step(k)
    prof.disable()
    ms = 1000 * (time.perf_counter() - t0) / steps
    stats = pstats.Stats(prof).stats  # type: ignore[attr-defined]
    parts = {
        f"{Path(f).stem}.{name}": round(1000 * ct / steps, 2)
        for (f, _, name), (_, _, _, ct, _) in stats.items()
        if "stereopose" in f and name in PARTS
    }
    return {"cameras": n, "ms_per_step": round(ms, 2), "parts_ms": parts}


# the 3D stage's parts reported (cumulative ms a step): association, triangulation, tracking
PARTS = (
    "epipolar_distances",
    "claim",
    "choose_views",
    "select_views",
    "triangulate_robust",
    "_triangulate",
    "update",
    "reconstruct",
)


def report(head: dict, results: list[dict]) -> None:
    md = [
        "# The fusion service at 16, 32 and 64 cameras",
        "",
        f"`python benchmarks/fusion_scale.py`, {head['date']}, "
        f"{head['machine'].replace(', one thread', '')}; mosquitto, `stereopose serve` "
        '(fusion: [input] detection = "nodes") and the replayer on this one machine; '
        f"{head['seconds']:.0f} s measured per set-up after warming; load average "
        f"{head['load_average'][0]} at the start, {head['load_average'][1]} at the end. "
        "The demo's 4 cameras' real detections (YOLO11n-pose, every frame) repeated to N "
        f"cameras (each copy its original's calibration), played by {NODES} replayed nodes on "
        "the wall clock's grid of the rate, with their health every second and each "
        "camera's picture once a second. Latency: from capture to the step's people on the "
        "broker, and to its zone events.",
        "",
        "| cameras (pairs) | rate | steps/s held | camera-frames used / sent | lost (late / "
        "over-full / refused / flood), partial steps, loop drops | capture -> people p50 / "
        "p95 s | -> zone event p50 / p95 s (n) | CPU cores (serve / mosquitto / replayer) "
        "| the service's work, ms a step (the largest stages) |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in sorted(results, key=lambda r: (r["cameras"], r["rate"])):
        lost = r["lost"]
        c = r["cpu_cores"]
        # "decode" is the wait for the nodes' frames (no decoding here), "detect" the nodes'
        work = {k: v for k, v in r["stage_ms"].items() if k not in ("decode", "detect")}
        top = sorted(work.items(), key=lambda kv: -kv[1])[:3]
        ev = (
            f"{r['event_latency_p50_s']} / {r['event_latency_p95_s']} ({r['events']})"
            if r["events"]
            else "-"
        )
        md.append(
            f"| {r['cameras']} ({r['camera_pairs']:,}) | {r['rate']:g} | {r['steps_per_s']}"
            f"{'' if r['held'] else ' (not held)'} | {r['camera_frames_used']:,} / "
            f"{r['camera_frames_sent']:,} | {lost['late']} / {lost['dropped']} / "
            f"{lost['refused']} / {lost['flood']}, {r['partial_steps']}, {r['loop_dropped']} | "
            f"{r['people_latency_p50_s']} / {r['people_latency_p95_s']} | {ev} | "
            f"{c['serve']} / {c['mosquitto']} / {c['replayer']} | "
            f"{', '.join(f'{k} {v}' for k, v in top)} |"
        )
    alone = head.get("stage_alone") or []
    if alone:
        md += [
            "",
            "## The 3D stage alone",
            "",
            "`Stage3D.step` in one process on one thread, the same people and rigs, nothing "
            "else running (ms a step; its parts' cumulative ms a step):",
            "",
            "| cameras | ms a step | steps/s on one core | association (epipolar "
            "distances) | triangulation (of which choosing the views) | tracking |",
            "|---|---|---|---|---|---|",
        ]
        for a in alone:
            p = a["parts_ms"]
            md.append(
                f"| {a['cameras']} | {a['ms_per_step']} | "
                f"{1000 / a['ms_per_step']:.0f} | "
                f"{p.get('affinity.epipolar_distances', '-')} | "
                f"{p.get('reconstructor._triangulate', '-')} "
                f"({p.get('_kernels.select_views', '-')}) | "
                f"{p.get('tracker.update', '-')} |"
            )
    md += ["", *head.get("notes", [])]
    save("fusion_scale", {**head, "results": results}, md)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cameras", default="16,32,64")
    ap.add_argument("--rates", default="5,12.5,25")
    ap.add_argument("--seconds", type=float, default=30.0)
    ap.add_argument("--frames", type=int, default=100, help="demo frames detected per camera")
    ap.add_argument("--note", action="append", default=[], help="a line for the report")
    ap.add_argument("--previous", type=Path, help="an earlier run's JSON lines to keep")
    args = ap.parse_args()
    mosquitto = shutil.which("mosquitto", path=os.pathsep.join([os.environ["PATH"], "/usr/sbin"]))
    if mosquitto is None or not demo_videos():
        sys.exit("needs mosquitto (Debian package) and the demo videos (make install)")
    load0 = os.getloadavg()[0]
    people, pictures = record(args.frames)
    print(f"recorded {sum(map(len, people))} camera-frames of the demo", flush=True)
    results = []
    if args.previous is not None:
        for line in args.previous.read_text().splitlines():
            if line.startswith('{"cameras"'):
                results.append(json.loads(line))
    done = {(r["cameras"], r["rate"]) for r in results}
    sizes = [int(x) for x in args.cameras.split(",")]
    for n in sizes:
        for rate in (float(x) for x in args.rates.split(",")):
            if (n, rate) in done:
                continue
            r = run_setup(n, rate, args.seconds, people, pictures, mosquitto)
            print(json.dumps(r), flush=True)
            results.append(r)
    alone = [stage_alone(n, people) for n in sizes]
    for a in alone:
        print(json.dumps({"stage_alone": a}), flush=True)
    head = {
        "date": datetime.date.today().isoformat(),
        "machine": machine(),
        "seconds": args.seconds,
        "notes": args.note,
        "stage_alone": alone,
        "load_average": [round(load0, 2), round(os.getloadavg()[0], 2)],
    }
    report(head, results)


if __name__ == "__main__":
    main()
