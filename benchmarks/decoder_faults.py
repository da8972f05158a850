"""A camera's decoder killed in a running `serve`: how soon its camera is down, how soon it is
back once its stream is good again, and whether any other camera or step is lost meanwhile.

`serve` runs with its defaults (each camera decoded in a process of its own) on the real demo's
4 cameras, shrunk once to 272x480 and served live over HTTP by real ffmpeg, looped. Every
`--every` seconds one camera's decoder process (cam03's; found by its connection to that
camera's server) is killed with SIGSEGV or SIGKILL in turn, `--rounds` times. The stream's
ffmpeg serves one client, so it ends with the decoder; it is served again `--away` seconds
later (3 by default: a stream that crashes its decoder is bad for a while; 0: at once, a
decoder crash alone), and the time it serves again is "the stream good again". The service's
`camera_timeout_s` is 1 s: a camera silent less than that is never down.

For each kill: the kill to its `camera_down` (aim: within 1 s), the stream good again to its
`camera_up` (aim: within 5 s); over the whole run, `service_stalled` events (aim: none) and
the other cameras' `camera_down` (aim: none). Times are this script's clock when it first saw
each event in the event log (polled every 20 ms).

    python benchmarks/decoder_faults.py [--rounds 6] [--every 12]

Results in results/decoder_faults.{json,md}.
"""

from __future__ import annotations

import argparse
import datetime
import os
import shutil
import signal
import sqlite3
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import psutil

from common import machine, save
from fuzzed_streams import Streams, serve_config, start_serve
from keeping_up import SUB_SIZE, substream
from stereopose.detection.models import demo_videos

VICTIM = "cam03"
SIGNALS = (signal.SIGSEGV, signal.SIGKILL)


def _decoder_of(serve: psutil.Process, port: int) -> int | None:
    """The pid of serve's decoder process connected to the stream on `port`."""
    for child in serve.children():
        try:
            conns = child.net_connections(kind="tcp")
        except psutil.Error:
            continue
        if any(c.raddr and c.raddr.port == port for c in conns):
            return child.pid
    return None


def _rows(db: Path, after: int) -> list[tuple[int, str, str | None]]:
    """(id, type, camera) of the camera and service events logged after id `after`."""
    try:
        with sqlite3.connect(f"file:{db}?mode=ro", uri=True, timeout=1.0) as con:
            return con.execute(
                "SELECT id, type, camera FROM events WHERE id > ? AND type IN "
                "('camera_down', 'camera_up', 'service_stalled') ORDER BY id",
                (after,),
            ).fetchall()
    except sqlite3.Error:
        return []


class Watch:
    """The event log, polled: when each event was first seen (this script's clock)."""

    def __init__(self, db: Path) -> None:
        self.db, self.last = db, 0
        self.seen: list[tuple[float, str, str | None]] = []

    def poll(self) -> None:
        now = time.monotonic()
        for i, kind, camera in _rows(self.db, self.last):
            self.last = i
            self.seen.append((now, kind, camera))

    def first(self, kind: str, camera: str, after: float) -> float | None:
        return next((t for t, k, c in self.seen if k == kind and c == camera and t >= after), None)


def run(rounds: int, every: float, away: float, work: Path, keep: Path | None = None) -> dict:
    videos = demo_videos()
    subs = {v.stem: substream(v, work / f"{v.stem}_sub.mp4") for v in videos}
    streams = Streams(subs, {}, work)
    config, out = serve_config(work, streams, videos)
    streams.start()
    log = work / "serve.log"
    proc = start_serve(config, log)
    serve = psutil.Process(proc.pid)
    watch = Watch(out / "events.sqlite")
    kills = []
    try:
        start = time.monotonic()
        while time.monotonic() - start < 120 and not (out / "status.json").is_file():
            time.sleep(0.2)
        time.sleep(every)  # every camera up and stepping
        watch.poll()
        for k in range(rounds):
            sig = SIGNALS[k % len(SIGNALS)]
            pid = _decoder_of(serve, streams.ports[VICTIM])
            if pid is None:
                kills.append({"signal": sig.name, "found": False})
                time.sleep(every)
                continue
            streams.held[VICTIM] = time.monotonic() + away
            os.kill(pid, sig)
            killed = time.monotonic()
            deadline = killed + every
            while time.monotonic() < deadline:
                watch.poll()
                time.sleep(0.02)
            restarted = streams.started_at.get(VICTIM, 0.0)
            good = restarted if restarted > killed else None  # its stream served anew
            down = watch.first("camera_down", VICTIM, killed)
            up = watch.first("camera_up", VICTIM, killed)
            kills.append(
                {
                    "signal": sig.name,
                    "found": True,
                    "down_s": None if down is None else down - killed,
                    "good_again_s": None if good is None else good - killed,
                    "up_after_good_s": None if up is None or good is None else up - good,
                }
            )
        end = time.monotonic()
        watch.poll()
        proc.send_signal(signal.SIGTERM)
        code = proc.wait(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
        streams.stop()
    text = log.read_text(errors="replace")
    if keep is not None:
        keep.mkdir(parents=True, exist_ok=True)
        (keep / "serve.log").write_text(text)
        shutil.copy(out / "events.sqlite", keep / "events.sqlite")
    others = sorted(n for n in subs if n != VICTIM)
    return {
        "away_s": away,
        "seconds": end - start,
        "exit_code": code,
        "kills": kills,
        "stalls": sum(1 for _, k, _ in watch.seen if k == "service_stalled"),
        "others_down": {
            n: sum(1 for _, k, c in watch.seen if k == "camera_down" and c == n) for n in others
        },
        "decoders_died": text.count("decoder died"),
        "tracebacks": text.count("Traceback"),
    }


def markdown(r: dict) -> list[str]:
    x = r["run"]
    kills = [k for k in x["kills"] if k.get("found")]

    def stat(key: str) -> str:
        xs = [k[key] for k in kills if k.get(key) is not None]
        if not xs:
            return "-"
        return f"median {np.median(xs):.2f} s, max {max(xs):.2f} s"

    md = [
        "# A camera's decoder killed in a running serve",
        "",
        f"{r['date']}, {r['machine'].replace('one thread', 'all cores')}. `{r['command']}`: "
        f"`serve` (its defaults) on the real demo's 4 cameras at {SUB_SIZE[0]}x{SUB_SIZE[1]}, "
        f"live over HTTP (ffmpeg, looped), `camera_timeout_s = 1`; {VICTIM}'s decoder process "
        f"killed {len(x['kills'])} times (SIGSEGV and SIGKILL in turn), its stream served "
        f"again {x['away_s']:g} s after each kill. Times are when this script "
        "first saw each event in the event log (polled every 20 ms).",
        "",
        f"- Killed to `camera_down` (aim 1 s): {stat('down_s')}.",
        f"- Stream good again (its ffmpeg serving anew) to `camera_up` (aim 5 s): "
        f"{stat('up_after_good_s')}; the stream was good again {stat('good_again_s')} after "
        "the kill.",
        f"- Over {x['seconds']:.0f} s: `service_stalled` **{x['stalls']}**; the other cameras' "
        f"`camera_down`: {x['others_down']}; decoders logged died: {x['decoders_died']}; "
        f"tracebacks: {x['tracebacks']}; exit {x['exit_code']} on SIGTERM.",
        "",
        "| kill | signal | down after (s) | stream good again after (s) | up after good (s) |",
        "|---|---|---|---|---|",
    ]
    for i, k in enumerate(x["kills"], 1):
        if not k.get("found"):
            md.append(f"| {i} | {k['signal']} | decoder not found | - | - |")
            continue

        def f(v):
            return "-" if v is None else f"{v:.2f}"

        md.append(
            f"| {i} | {k['signal']} | {f(k['down_s'])} | {f(k['good_again_s'])} | "
            f"{f(k['up_after_good_s'])} |"
        )
    return md


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=6)
    ap.add_argument("--every", type=float, default=12.0)
    ap.add_argument("--away", type=float, default=3.0, help="seconds the stream stays away")
    ap.add_argument("--keep", type=Path, help="keep serve's log and event log in this folder")
    args = ap.parse_args()
    if len(demo_videos()) != 4:
        sys.exit("the demo videos are not in the cache: run `stereopose demo` once")
    with tempfile.TemporaryDirectory() as tmp:
        result = run(args.rounds, args.every, args.away, Path(tmp), args.keep)
    r = {
        "date": datetime.date.today().isoformat(),
        "machine": machine(),
        "command": " ".join(["python benchmarks/decoder_faults.py", *sys.argv[1:]]),
        "run": result,
    }
    save("decoder_faults", r, markdown(r))


if __name__ == "__main__":
    main()
