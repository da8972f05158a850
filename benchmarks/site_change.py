"""A site change while serving: how soon a new zone's events start after an admin's save, and
whether the frame loop stalls around it.

`stereopose serve` runs the real demo (its 4 videos looped, the default detector). An admin
adds a zone covering the whole floor through `PUT /api/site`, later takes it out again, then
adds it again under another name (3 changes). For each: seconds from the PUT's answer to the
new zone's first `enter` in the event log (the zone's removal: to its last occupant's `exit`),
and from the /metrics frame counter sampled every 50 ms, the steps per second and the longest
time without a step in the 10 s before the change and the 10 s after it.

    PYTHONPATH=tests python benchmarks/site_change.py [--changes 3]

Results in results/site_change.{json,md}.
"""

from __future__ import annotations

import argparse
import datetime
import itertools
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import httpx

from brokers import free_port
from common import machine, save
from served import log_rows
from stereopose.pipeline.demo import write_serve_demo_config

WINDOW_S = 10.0
SAMPLE_S = 0.05
FRAMES = re.compile(r"^stereopose_frames_total (\S+)$", re.M)


def _zone(name: str) -> dict:
    return {
        "name": name,
        "kind": "restricted",
        "polygon": [[-6.0, -6.0], [6.0, -6.0], [6.0, 6.0], [-6.0, 6.0]],
        "z": [0.0, 2.5],
    }


def _frames(c: httpx.Client) -> float:
    found = FRAMES.search(c.get("/metrics").text)
    return float(found.group(1)) if found else float("nan")


def _watch(c: httpx.Client, seconds: float) -> list[tuple[float, float]]:
    """(time, frames processed) every SAMPLE_S for `seconds`."""
    out, end = [], time.monotonic() + seconds
    while time.monotonic() < end:
        out.append((time.monotonic(), _frames(c)))
        time.sleep(SAMPLE_S)
    return out


def _loop(samples: list[tuple[float, float]]) -> dict:
    """Steps per second and the longest time the counter stood still (ms)."""
    (t0, f0), (t1, f1) = samples[0], samples[-1]
    moved = [t for (t, f), (_, g) in itertools.pairwise(samples) if f != g]
    moved = [t0, *moved, t1]
    gap = max(b - a for a, b in itertools.pairwise(moved))
    return {"steps_per_s": (f1 - f0) / (t1 - t0), "longest_gap_ms": 1000 * gap}


def _until(condition, timeout_s: float = 60.0) -> float:
    start = time.monotonic()
    while not condition():
        if time.monotonic() - start > timeout_s:
            raise TimeoutError("the change's events did not come")
        time.sleep(0.02)
    return time.monotonic() - start


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--changes", type=int, default=3)
    args = ap.parse_args()
    runs = []
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        port = free_port()
        config = write_serve_demo_config(work / "demo", work / "data", port)
        db = work / "data" / "events.sqlite"
        add = [sys.executable, "-m", "stereopose.cli", "users", "add", "ada", "--role", "admin"]
        subprocess.run([*add, "--config", str(config)], input=b"ada's passphrase\n", check=True)
        log = open(work / "serve.log", "ab")  # noqa: SIM115
        proc = subprocess.Popen(
            [sys.executable, "-m", "stereopose.cli", "serve", str(config)],
            stdout=log,
            stderr=subprocess.STDOUT,
        )
        try:
            c = httpx.Client(base_url=f"http://127.0.0.1:{port}", timeout=30)
            _until(lambda: _up(c, proc), timeout_s=180)
            r = c.post("/api/login", json={"username": "ada", "password": "ada's passphrase"})
            c.headers["X-CSRF-Token"] = r.json()["csrf"]
            _until(lambda: log_rows(db, "SELECT 1 FROM events WHERE person >= 0 LIMIT 1"), 180)
            for k in range(args.changes):
                name = f"whole_floor_{k // 2}"
                adding = k % 2 == 0
                before = _watch(c, WINDOW_S)
                got = c.get("/api/site").json()
                zones = [z for z in got["site"]["zones"] if not z["name"].startswith("whole")]
                site = {**got["site"], "zones": [*zones, _zone(name)] if adding else zones}
                r = c.put("/api/site", json={"version": got["version"], "site": site})
                r.raise_for_status()
                kind = "enter" if adding else "exit"
                first = f"SELECT 1 FROM events WHERE zone = '{name}' AND type = '{kind}' LIMIT 1"
                if not adding:
                    mark = log_rows(db, "SELECT COALESCE(MAX(id), 0) FROM events")[0][0]
                    first = first.replace("WHERE", f"WHERE id > {mark} AND")
                latency = _until(lambda q=first: bool(log_rows(db, q)))
                after = _watch(c, WINDOW_S)
                run = {
                    "change": f"{'added' if adding else 'removed'} {name}",
                    "first_event": kind,
                    "latency_s": latency,
                    "before": _loop(before),
                    "after": _loop(after),
                }
                runs.append(run)
                print(run, flush=True)
            if proc.poll() is not None:
                sys.exit(f"serve ended: {(work / 'serve.log').read_text()[-2000:]}")
        finally:
            proc.terminate()
            proc.wait(timeout=60)
            log.close()
    r = {"date": datetime.date.today().isoformat(), "machine": machine(), "runs": runs}
    save("site_change", r, markdown(r))


def _up(c: httpx.Client, proc: subprocess.Popen) -> bool:
    if proc.poll() is not None:
        raise SystemExit("serve ended before its API answered")
    try:
        return c.get("/api/health", timeout=5).status_code < 500
    except httpx.HTTPError:
        return False


def markdown(r: dict) -> list[str]:
    md = [
        "# A site change while serving",
        "",
        f"`PYTHONPATH=tests python benchmarks/site_change.py`, {r['date']}, {r['machine']}. "
        "`stereopose serve` on the real demo (4 looped videos, default detector); an admin's "
        "`PUT /api/site` adds a zone covering the floor, takes it out, adds it again. Latency: "
        "from the PUT's answer to the zone's first `enter` (its removal: its occupants' "
        "`exit`) in the event log. Steps/s and the longest time without a step from "
        "/metrics' frame counter (sampled every 50 ms) in the 10 s before and after.",
        "",
        "| change | latency s | steps/s before / after | longest gap ms before / after |",
        "|---|---|---|---|",
    ]
    for run in r["runs"]:
        b, a = run["before"], run["after"]
        md.append(
            f"| {run['change']} ({run['first_event']}) | {run['latency_s']:.2f} | "
            f"{b['steps_per_s']:.1f} / {a['steps_per_s']:.1f} | "
            f"{b['longest_gap_ms']:.0f} / {a['longest_gap_ms']:.0f} |"
        )
    return md


if __name__ == "__main__":
    main()
