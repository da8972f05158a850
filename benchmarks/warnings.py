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

    python benchmarks/warnings.py [--seconds 60]

Results in results/warnings.{json,md}.
"""

from __future__ import annotations

import argparse
import datetime
import sqlite3
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
import psutil

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))
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
    """The beacon's coil polled from its IO module: each time it is read on after off."""

    def __init__(self, module: IoModule) -> None:
        from pymodbus.client import ModbusTcpClient

        self.client = ModbusTcpClient("127.0.0.1", port=module.port, timeout=2, retries=0)
        self.on_at: list[float] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        self.client.connect()
        was = False
        while not self._stop.wait(0.01):
            answer = self.client.read_coils(0, count=1, device_id=1)
            on = not answer.isError() and bool(answer.bits[0])
            if on and not was:
                self.on_at.append(time.time())
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
    starts = sorted(p[0] for p in ear.packets if p[1])  # talkspurts' first packets
    # arrival in the listener's clock: monotonic; the events' times are Unix: moved over
    offset = time.time() - time.monotonic()
    starts = [s + offset for s in starts]
    audio, coils, used = [], [], set()
    for wall, _type, _person in alarms:
        later = [s for s in starts if s >= wall and s not in used]
        if later:
            used.add(later[0])
            audio.append(later[0] - wall)
        if coil is not None:
            on = [c for c in coil.on_at if c >= wall]
            if on and on[0] - wall < 5.0:
                coils.append(on[0] - wall)
    return {
        "seconds": seconds,
        "alarms": len(alarms),
        "talkspurts": len(starts),
        "capture_to_audio_s": audio,
        "capture_to_coil_s": coils,
        "cpu_per_s": cpu,
        "log_tail": log.read_text()[-2000:],
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
        f"| capture to the beacon's coil read on, s | {f(_p(c, 50))} | {f(_p(c, 95))} | "
        f"{len(c)} |",
        "",
        f"Alarms of the busbar: {on['alarms']}; talkspurts heard: {on['talkspurts']}. The "
        f"service's CPU: {on['cpu_per_s']:.2f} CPU s per s with the warnings, "
        f"{off['cpu_per_s']:.2f} without (the same demo, another run).",
    ]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=60.0)
    args = ap.parse_args()
    r: dict = {
        "date": datetime.date.today().isoformat(),
        "machine": machine().replace("one thread", "all cores"),
        "command": " ".join(["python benchmarks/warnings.py", *sys.argv[1:]]),
    }
    with tempfile.TemporaryDirectory() as tmp:
        r["with"] = one_run(Path(tmp) / "with", args.seconds, True)
        print({k: v for k, v in r["with"].items() if k != "log_tail"}, flush=True)
        r["without"] = one_run(Path(tmp) / "without", args.seconds, False)
    for k in ("with", "without"):
        r[k].pop("log_tail")
    save("warnings", r, markdown(r))


if __name__ == "__main__":
    main()
