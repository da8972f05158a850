"""Warnings on site, measured on the real demo served: `stereopose serve` on the demo's 4
cameras (its videos looped on the wall clock, as `serve --demo` plays them), its site with one
IP speaker (RTP, G.711 mu-law) and one Modbus TCP IO module (pymodbus's own server) covering
the energized busbar the walker reaches into.

For every energized-zone alarm of the busbar in the event log (its capture time: the run's
wall_start + the event's t):
- capture to the first RTP packet of its message at the speaker's address (a UDP listener:
  the first talkspurt that starts after the capture; repeat_s is long, so every talkspurt is
  a new hazard's message), p50 and p95;
- capture to the beacon's coil read on from the IO module (a Modbus client polling it every
  10 ms while it is off): p50 and p95, for the alarms that found the coil off;
- the CPU the service used, against the same run with no warnings on site (CPU seconds per
  wall second of the whole process, psutil).

    python benchmarks/warnings_on_site.py [--seconds 90]

Results in results/warnings_on_site.{json,md}. (Not `warnings.py`: a script's folder comes
first on Python's path, and that name is the standard library's.)
"""

from __future__ import annotations

import os
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
import argparse
import datetime
import sqlite3
import subprocess
import tempfile
import threading
import time
import tomllib
from pathlib import Path

import numpy as np
import psutil

sys.path.insert(0, HERE)
sys.path.append(os.path.join(os.path.dirname(HERE), "tests"))
from common import machine, save
from modbus_device import IoModule
from rtp_listener import Listener
from stereopose.pipeline.demo import write_serve_demo_config
from streams import free_port

WARNINGS = """
[warnings]
language = "en"
repeat_s = 600.0

[[speakers]]
name = "pa_busbar"
url = "rtp://127.0.0.1:{rtp}"
zones = ["overhead_busbar"]

[[signals]]
name = "tower"
host = "127.0.0.1"
port = {modbus}
coils = {{ beacon = 0 }}
zones = ["overhead_busbar"]
"""

ALARMS = (
    "SELECT r.wall_start + e.t, e.type, e.person FROM events e JOIN runs r ON e.run = r.id "
    "WHERE e.zone = 'overhead_busbar' AND e.kind = 'energized' "
    "AND e.type IN ('enter', 'approach') ORDER BY e.id"
)


class Coil:
    """The beacon's coil polled from its IO module: each time it changed."""

    def __init__(self, module: IoModule) -> None:
        from pymodbus.client import ModbusTcpClient

        self.client = ModbusTcpClient("127.0.0.1", port=module.port, timeout=2, retries=0)
        self.changes: list[tuple[float, bool]] = []  # (when, on) each time it changed
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        self.client.connect()
        was = False
        while not self._stop.wait(0.01):
            answer = self.client.read_coils(0, count=1, device_id=1)
            on = not answer.isError() and bool(answer.bits[0])
            if on != was:
                self.changes.append((time.time(), on))
            was = on

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(5)
        self.client.close()


def one_run(work: Path, seconds: float, warnings: bool) -> dict:
    config = write_serve_demo_config(work / "demo", work / "data", free_port(), imgsz=640)
    ear = Listener()
    module = IoModule().start() if warnings else None
    if warnings:
        site = work / "demo" / "demo_site.toml"
        site.write_text(site.read_text() + WARNINGS.format(rtp=ear.port, modbus=module.port))
    coil = Coil(module) if module is not None else None
    log = work / "serve.log"
    with open(log, "ab") as f:
        proc = subprocess.Popen(
            [sys.executable, "-m", "stereopose.cli", "serve", str(config)],
            stdout=f,
            stderr=subprocess.STDOUT,
        )
    ps = psutil.Process(proc.pid)
    db = work / "data" / "events.sqlite"
    try:
        deadline = time.monotonic() + 300
        while not db.exists() and time.monotonic() < deadline and proc.poll() is None:
            time.sleep(0.2)
        cpu0, t0 = sum(ps.cpu_times()[:2]), time.monotonic()
        ear.take(lambda: time.monotonic() - t0 > seconds)
        cpu = (sum(ps.cpu_times()[:2]) - cpu0) / (time.monotonic() - t0)
    finally:
        proc.terminate()
        proc.wait(60)
        if coil is not None:
            coil.stop()
        if module is not None:
            module.stop()
    with sqlite3.connect(db) as c:
        alarms = c.execute(ALARMS).fetchall()
    # arrival in the listener's clock: monotonic; the events' times are Unix: moved over
    offset = time.time() - time.monotonic()
    arrivals = [(p[0] + offset, p[1]) for p in ear.packets]
    starts = sorted(t for t, first in arrivals if first)  # the talkspurts' first packets
    saying = sorted(t for t, first in arrivals if not first)
    audio, waited, missed, coils = [], [], 0, []
    for wall, _type, _person in alarms:
        later = [s for s in starts if s >= wall]
        if later and later[0] - wall <= 1.0:
            audio.append(later[0] - wall)  # a message started for it (or cut in)
        elif any(wall <= t <= wall + 0.2 for t in saying):
            # the speaker was saying a more urgent (or as urgent) message of its zone: this
            # one's waits for its end (never two at once)
            waited.append(later[0] - wall if later else float("nan"))
        else:
            missed += 1
        if coil is not None:
            before = [on for t, on in coil.changes if t < wall]
            if before and before[-1]:
                continue  # already on: its hazard went on
            on = [t for t, now in coil.changes if t >= wall and now]
            if on:
                coils.append(on[0] - wall)
    return {
        "seconds": seconds,
        "alarms": len(alarms),
        "talkspurts": len(starts),
        "capture_to_audio_s": audio,
        "waited_s": waited,
        "missed": missed,
        "capture_to_coil_s": coils,
        "cpu_per_s": cpu,
        "log_tail": log.read_text()[-2000:],
    }


def output_cost(steps: int = 2000) -> dict:
    """The outputs' own cost: the warner's step (a worker's hand 0.3 m from the busbar, a
    speaker and a signal), a speaker's thread while it talks, a signal's write."""
    from stereopose.fence import FenceMonitor, load_site
    from stereopose.onsite.modbus import Signal
    from stereopose.onsite.phrases import Phrasebook
    from stereopose.onsite.rtp import Speaker
    from stereopose.onsite.settings import parse_warnings
    from stereopose.onsite.speech import Speech
    from stereopose.onsite.warner import Warner
    from stereopose.pipeline.demo import write_demo_config
    from stereopose.skeleton import JOINTS
    from stereopose.types import People3D

    with tempfile.TemporaryDirectory() as tmp:
        site = load_site(write_demo_config(Path(tmp)).parent / "demo_site.toml")
    ear, module = Listener(), IoModule().start()
    doc = tomllib.loads(WARNINGS.format(rtp=ear.port, modbus=module.port))
    w = parse_warnings(doc, [z.name for z in site.zones])
    speaker = Speaker(w.speakers[0], w.repeat_s)
    signal = Signal(w.signals[0])
    warner = Warner(site.zones, w, Phrasebook(w, site.zones, Speech()), {"pa": speaker},
                    {"tower": signal})  # fmt: skip
    fences = FenceMonitor(site, fps=20.0)
    J = np.tile([-0.2, 0.3, 1.0], (17, 1))  # a worker beside the busbar, facing +y
    J[JOINTS.index("left_shoulder")] = [-0.4, 0.3, 1.45]
    J[JOINTS.index("right_shoulder")] = [0.0, 0.3, 1.45]
    J[JOINTS.index("right_wrist")] = [-0.5, 0.15, 1.6]  # 0.15 m from its edge
    try:
        times = []
        for k in range(steps):
            p = People3D(k, J[None], np.ones((1, 17)), np.array([1]), np.full((1, 17), np.nan),
                         np.full((1, 17), 2), np.zeros((1, 0), int), t=k * 0.05)  # fmt: skip
            fences.update(p)
            t0 = time.perf_counter()
            warner.step(p.t, k, p, fences)
            times.append(time.perf_counter() - t0)
        # a speaker's thread alone while it talks: the process's CPU over 3 s of speech
        speaker.quiet()
        t0, c0 = time.monotonic(), time.process_time()
        speaker.want(("busbar", "enter", 9), 1, np.zeros(8000 * 3, np.int16))
        ear.take(lambda: time.monotonic() - t0 > 3.0)
        share = (time.process_time() - c0) / (time.monotonic() - t0)
        w0 = signal.figures["writes"]
        t1 = time.monotonic()
        for k in range(50):
            signal.want({"beacon"} if k % 2 == 0 else set())
            while signal.figures["writes"] < w0 + k + 1:
                time.sleep(0.001)
        write_ms = 1000 * (time.monotonic() - t1) / 50
    finally:
        warner.close()
        module.stop()
    return {
        "warner_step_ms": 1000 * float(np.median(times[20:])),
        "speaker_cpu_share": share,
        "signal_write_ms": write_ms,
    }


def _p(values: list[float], q: float) -> float | None:
    return float(np.percentile(values, q)) if values else None


def markdown(r: dict) -> list[str]:
    on, off = r["with"], r["without"]

    def f(v: float | None) -> str:
        return "-" if v is None else f"{v:.3f}"

    a, c = on["capture_to_audio_s"], on["capture_to_coil_s"]
    return [
        "# Warnings on site",
        "",
        f"`{r['command']}`, {r['date']}, {r['machine']}. `stereopose serve` on the real demo "
        f"(4 cameras looped on the wall clock, YOLO11n-pose at 640) for {on['seconds']:g} s, "
        "one RTP speaker and one Modbus TCP IO module (pymodbus's server) covering the busbar; "
        "times from each busbar alarm's capture.",
        "",
        "| figure | p50 | p95 | n |",
        "|---|---|---|---|",
        f"| capture to the first RTP packet of its message, s | {f(_p(a, 50))} | "
        f"{f(_p(a, 95))} | {len(a)} |",
        f"| capture to the beacon's coil read on, s | {f(_p(c, 50))} | {f(_p(c, 95))} | {len(c)} |",
        "",
        f"Alarms of the busbar: {on['alarms']}; talkspurts heard: {on['talkspurts']}; "
        f"{len(on['waited_s'])} alarm(s) came while the speaker was saying another message of "
        "its zone, as urgent or more, and waited for its end, as one speaker never says two "
        "at once (waits: "
        + ", ".join(f"{w:.1f} s" for w in on["waited_s"])
        + f"); {on['missed']} alarm(s) without a message. The beacon's coil was already on for "
        f"{on['alarms'] - len(c)} alarm(s) (its hazard went on). The service's whole CPU: "
        f"{on['cpu_per_s']:.2f} CPU s per s with the warnings, {off['cpu_per_s']:.2f} without "
        "(the same demo, another run: detection fills both cores either way).",
        "",
        f"The outputs' own cost, in-process: the warner's step with a worker at the busbar "
        f"{r['cost']['warner_step_ms']:.3f} ms; a speaker saying a message "
        f"{100 * r['cost']['speaker_cpu_share']:.2f} % of a core while it talks; a signal "
        f"{r['cost']['signal_write_ms']:.2f} ms per write of its coils.",
    ]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=60.0)
    args = ap.parse_args()
    r: dict = {
        "date": datetime.date.today().isoformat(),
        "machine": machine().replace("one thread", "all cores"),
        "command": " ".join(["python benchmarks/warnings_on_site.py", *sys.argv[1:]]),
    }
    r["cost"] = output_cost()
    print(r["cost"], flush=True)
    with tempfile.TemporaryDirectory() as tmp:
        r["with"] = one_run(Path(tmp) / "with", args.seconds, True)
        print({k: v for k, v in r["with"].items() if k != "log_tail"}, flush=True)
        r["without"] = one_run(Path(tmp) / "without", args.seconds, False)
    for k in ("with", "without"):
        r[k].pop("log_tail")
    save("warnings_on_site", r, markdown(r))


if __name__ == "__main__":
    main()
