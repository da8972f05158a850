"""The control room under a fleet: N simulated sites, each a real MQTT client, through a real
mosquitto, into a real `stereopose control-room` process with its SQLite store.

Each site publishes what a site's `serve` publishes at the demo's rates: `available` (online,
retained, and its last will), people at `--people-hz` (QoS 0), and events at `--events-hz`
(Poisson) through the outbox protocol (`log/events`, QoS 1, ids chained by `prev`; a replay
asked for is answered from the site's own list). Every event carries the time it was
published; the control room's store records when it committed it (readable at /api/events
from then on): latency = stored_at - sent. At the end: events sent and stored per site
(nothing lost, nothing twice), the store's rate, latency p50/p95/max, the control room's
memory (RSS) and CPU, for each N in turn on one machine (sites, broker and control room share
its cores, so these figures are the control room's floor, not its ceiling).

    python benchmarks/fleet.py [--sites 100,300,1000] [--seconds 60]

Results: benchmarks/results/fleet.{md,json}.
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import os
import random
import sqlite3
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import paho.mqtt.client as paho

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from common import machine, save

PREFIX = "stereopose"


class Site:
    def __init__(self, name: str, port: int, rng: random.Random) -> None:
        self.name, self.rng = name, rng
        self.sent: list[dict] = []
        self.lock = threading.Lock()
        self.c = paho.Client(paho.CallbackAPIVersion.VERSION2, protocol=paho.MQTTv311,
                             client_id=f"fleet-{name}")  # fmt: skip
        self.c.will_set(f"{PREFIX}/{name}/available", "offline", qos=1, retain=True)
        self.c.on_connect = self._on_connect
        self.c.on_message = self._on_message
        self.c.max_inflight_messages_set(100)
        self.c.max_queued_messages_set(0)
        self.c.connect_async("127.0.0.1", port, keepalive=30)
        self.c.loop_start()

    def _on_connect(self, client, userdata, flags, reason, props) -> None:
        client.publish(f"{PREFIX}/{self.name}/available", "online", qos=1, retain=True)
        client.subscribe(f"{PREFIX}/{self.name}/log/replay", qos=1)

    def _on_message(self, client, userdata, msg) -> None:
        after = json.loads(msg.payload).get("after_id", 0)
        with self.lock:
            again = [e for e in self.sent if e["id"] > after]
        for e in again:
            client.publish(f"{PREFIX}/{self.name}/log/events", json.dumps(e), qos=1)

    def event(self) -> None:
        with self.lock:
            prev = self.sent[-1]["id"] if self.sent else 0
            e = {"site": self.name, "id": prev + 1, "prev": prev, "type": "enter",
                 "zone": "busbar", "person": self.rng.randrange(5), "level": "alarm",
                 "wall_t": time.time(), "sent": time.time()}  # fmt: skip
            self.sent.append(e)
        self.c.publish(f"{PREFIX}/{self.name}/log/events", json.dumps(e), qos=1)

    def people(self) -> None:
        n = self.rng.randrange(4)
        body = {"t": time.time(), "people": [{"id": i, "position": [1.0 * i, 2.0],
                                              "heading_deg": 90.0} for i in range(n)]}  # fmt: skip
        self.c.publish(f"{PREFIX}/{self.name}/people", json.dumps(body), qos=0)

    def close(self) -> None:
        self.c.disconnect()
        self.c.loop_stop()


def _proc_figures(pid: int) -> tuple[float, float]:
    """(RSS MB, CPU seconds user+system) of a process."""
    rss = 0.0
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            rss = int(line.split()[1]) / 1024
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    cpu = (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    return rss, cpu


def one(n_sites: int, seconds: float, events_hz: float, people_hz: float, work: Path) -> dict:
    from brokers import Broker, free_port

    broker = Broker(work / f"broker-{n_sites}")
    broker.config.write_text(broker.config.read_text() + "max_connections -1\n")
    broker.start()
    http_port = free_port()
    room_dir = work / f"room-{n_sites}"
    room_dir.mkdir()
    config = room_dir / "control.toml"
    config.write_text(f'output = "data"\n\n[serve]\nport = {http_port}\n\n[mqtt]\n'
                      f'host = "127.0.0.1"\nport = {broker.port}\n')  # fmt: skip
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    log = open(room_dir / "room.log", "ab")  # noqa: SIM115
    cmd = [sys.executable, "-m", "stereopose.cli", "control-room", str(config)]
    room = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, env=env)
    time.sleep(3)
    rng = random.Random(n_sites)
    sites = [Site(f"site{i:04d}", broker.port, random.Random(i)) for i in range(n_sites)]
    time.sleep(2 + n_sites / 200)  # every site connected
    rss0, cpu0 = _proc_figures(room.pid)
    start = time.monotonic()
    next_people = start
    tick = 0.05
    rss_max = rss0
    while time.monotonic() - start < seconds:
        now = time.monotonic()
        for s in sites:
            if rng.random() < events_hz * tick:
                s.event()
        if people_hz and now >= next_people:
            for s in sites:
                s.people()
            next_people += 1.0 / people_hz
        rss_max = max(rss_max, _proc_figures(room.pid)[0])
        time.sleep(max(0.0, tick - (time.monotonic() - now)))
    elapsed = time.monotonic() - start
    sent = sum(len(s.sent) for s in sites)
    db = room_dir / "data" / "control.sqlite"

    def stored() -> int:
        con = sqlite3.connect(f"file:{db}?mode=ro", uri=True, timeout=5)
        try:
            return con.execute("SELECT COUNT(*) FROM events").fetchone()[0]
        finally:
            con.close()

    deadline = time.monotonic() + 60
    while stored() < sent and time.monotonic() < deadline:
        time.sleep(0.5)
    drained_s = time.monotonic() - start - elapsed
    _, cpu1 = _proc_figures(room.pid)
    con = sqlite3.connect(f"file:{db}?mode=ro", uri=True, timeout=5)
    rows = con.execute("SELECT site, id, stored_at, record FROM events").fetchall()
    con.close()
    room.terminate()
    room.wait(timeout=30)
    log.close()
    for s in sites:
        s.close()
    broker.stop()
    lat = sorted(st - json.loads(rec)["sent"] for _, _, st, rec in rows)
    by_site = {s.name: {e["id"] for e in s.sent} for s in sites}
    got: dict[str, list[int]] = {}
    for site, i, _, _ in rows:
        got.setdefault(site, []).append(i)
    lost = sum(len(ids - set(got.get(name, []))) for name, ids in by_site.items())
    twice = sum(len(v) - len(set(v)) for v in got.values())

    def q(p: float) -> float | None:
        return round(lat[min(len(lat) - 1, int(p * len(lat)))], 3) if lat else None

    return {
        "sites": n_sites,
        "seconds": round(elapsed, 1),
        "events_sent": sent,
        "events_stored": len(rows),
        "lost": lost,
        "stored_twice": twice,
        "events_per_s": round(sent / elapsed, 1),
        "people_msgs_per_s": round(n_sites * people_hz, 1),
        "drain_after_end_s": round(max(0.0, drained_s), 1),
        "latency_s": {"p50": q(0.5), "p95": q(0.95), "max": round(lat[-1], 3) if lat else None},
        "control_room_rss_mb": {"start": round(rss0, 1), "max": round(rss_max, 1)},
        "control_room_cpu_share": round((cpu1 - cpu0) / (elapsed + drained_s), 3),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sites", default="100,300,1000")
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--events-hz", type=float, default=0.5, help="events per site per second")
    ap.add_argument("--people-hz", type=float, default=5.0)
    args = ap.parse_args()
    runs = []
    with tempfile.TemporaryDirectory() as tmp:
        for n in [int(x) for x in args.sites.split(",")]:
            r = one(n, args.seconds, args.events_hz, args.people_hz, Path(tmp))
            print(r, flush=True)
            runs.append(r)
    results = {"date": dt.date.today().isoformat(),
               "machine": machine().replace(", one thread", ""),
               "events_hz_per_site": args.events_hz, "people_hz_per_site": args.people_hz,
               "runs": runs}  # fmt: skip
    save("fleet", results, markdown(results))


def markdown(r: dict) -> list[str]:
    md = [
        "# The control room under a fleet of simulated sites",
        "",
        f"`python benchmarks/fleet.py`, {r['date']}, {r['machine']}. Each site a real MQTT "
        f"client: events at {r['events_hz_per_site']} per second (Poisson) through the outbox "
        f"protocol, people at {r['people_hz_per_site']} Hz (QoS 0, through the broker, not "
        "stored), availability retained; one mosquitto; `stereopose control-room` with its "
        "SQLite store. Sites, broker and control room share the machine's 2 cores. Latency: "
        "the store's commit (from then on readable at /api/events) minus the site's publish.",
        "",
        "| sites | events/s in | people msgs/s | stored / sent | lost | stored twice | "
        "latency p50 / p95 / max s | drained after the end s | control room RSS MB "
        "start / max | control room CPU (cores) |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for x in r["runs"]:
        lat = x["latency_s"]
        md.append(f"| {x['sites']} | {x['events_per_s']} | {x['people_msgs_per_s']} | "
                  f"{x['events_stored']} / {x['events_sent']} | {x['lost']} | "
                  f"{x['stored_twice']} | {lat['p50']} / {lat['p95']} / {lat['max']} | "
                  f"{x['drain_after_end_s']} | {x['control_room_rss_mb']['start']} / "
                  f"{x['control_room_rss_mb']['max']} | "
                  f"{x['control_room_cpu_share']} |")  # fmt: skip
    md += ["", "A second control-room worker (MQTT shared subscriptions) and PostgreSQL are not "
           "in this version, so neither is measured."]  # fmt: skip
    return md


if __name__ == "__main__":
    main()
