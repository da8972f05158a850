"""Fuzzed live streams: `serve` on the real demo's 4 cameras, 2 of them fed corrupt H.264 and
H.265, for `--seconds` (600 by default).

The 4 demo videos, shrunk once to 272x480 (the calibration scaled to match), are served live by
real ffmpeg (imageio-ffmpeg), in real time with stream copy, either over HTTP as MPEG-TS
(`--transport http`, ffmpeg serving each camera itself) or over RTSP (`--transport rtsp`:
each camera's ffmpeg pushes RTP to an RTSP server, Debian's `rtsp-server-perl`, which `serve`
reads from as from an IP camera, its RTP over UDP):
- cam01 and cam02: H.264, looped, good;
- cam03 (H.264) and cam04 (H.265): each served as a run of spoilt copies of its stream, one
  after another, each played once: bits flipped at random (1 in 2,000 to 1 in 200,000 bytes,
  headers and all), or cut short at a random byte. A copy that ends, or that makes the
  serving ffmpeg give up, ends the camera's stream: the camera is lost, and connects to the
  next copy, served GAP_S later (a camera away for a while: each copy one loss).

`serve` runs as a child process with its defaults (each camera decoded in a process of its
own, [input] decoders = "process"). Every second: whether it is up, its steps (status.json),
and the resident memory of the service and of its decoders. At the end: each camera's
`camera_down` and `camera_up` events against the spoilt copies served, stalls
(`service_stalled`), the decoders restarted and why (its log), tracebacks, memory from the
second minute to the last, and serve's exit on SIGTERM.

    python benchmarks/fuzzed_streams.py [--seconds 600] [--transport rtsp]

Results in results/fuzzed_streams.{json,md} (--name: another file).
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import datetime
import json
import os
import random
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from importlib import resources
from pathlib import Path

import numpy as np
import psutil

from common import machine, save
from keeping_up import SUB_SIZE, ffmpeg, free_port, substream
from stereopose.calibration.formats import load_calibration, save_calibration
from stereopose.detection.models import demo_videos
from stereopose.errors import StereoposeError
from stereopose.io.sinks.events import query_events
from stereopose.types import Rig

FUZZED = {"cam03": "h264", "cam04": "hevc"}  # the cameras fed spoilt streams, and their codec
COPY_S = 12.0  # each spoilt copy's length, seconds of video
GAP_S = 3.0  # a fuzzed camera's stream away this long between two copies: each one lost
FLIP_RATES = (1 / 2_000, 1 / 20_000, 1 / 200_000)  # bits flipped per byte, in turn
CUT_EVERY = 4  # every 4th copy cut short instead


def _ts(video: Path, out: Path, codec: str) -> Path:
    """`video` (the substream, 100 frames) looped to COPY_S as MPEG-TS, in `codec` (h264:
    copied; hevc: encoded with libx265)."""
    enc = ["-c:v", "copy"] if codec == "h264" else ["-c:v", "libx265", "-preset", "ultrafast"]
    cmd = [ffmpeg(), "-loglevel", "error", "-y", "-stream_loop", "-1", "-i", str(video)]
    cmd += ["-t", str(COPY_S), "-an"]
    cmd += [*enc, "-x265-params", "log-level=error"] if codec == "hevc" else enc
    subprocess.run([*cmd, "-f", "mpegts", str(out)], check=True, timeout=300)
    return out


def spoil(good: bytes, k: int, rng: random.Random) -> tuple[bytes, str]:
    """The k-th spoilt copy of a stream and what was done to it."""
    if k % CUT_EVERY == CUT_EVERY - 1:
        at = rng.randrange(len(good) // 10, len(good))
        return good[:at], f"cut at byte {at} of {len(good)}"
    rate = FLIP_RATES[k % len(FLIP_RATES)]
    data = np.frombuffer(good, np.uint8).copy()
    n = max(1, int(len(data) * rate))
    where = np.array([rng.randrange(len(data)) for _ in range(n)])
    data[where] ^= np.array([1 << rng.randrange(8) for _ in range(n)], np.uint8)
    return data.tobytes(), f"{n} bits flipped"


def _server(source: Path, url: str, loop: bool) -> subprocess.Popen:
    """ffmpeg playing `source` in real time to `url`: served there itself (http://, one
    client), or pushed to an RTSP server's mount (rtsp://)."""
    cmd = [ffmpeg(), "-loglevel", "quiet", "-re"]
    cmd += ["-stream_loop", "-1"] if loop else []
    cmd += ["-i", str(source), "-an", "-c", "copy"]
    if url.startswith("rtsp://"):
        cmd += ["-f", "rtsp", "-rtsp_transport", "udp"]
    else:
        cmd += ["-f", "mpegts", "-listen", "1"]
    return subprocess.Popen([*cmd, url], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


class RtspServer:
    """Debian's rtsp-server-perl on local ports: sources push to `push_url(name)` (ANNOUNCE,
    RECORD), clients read `url(name)` (PLAY, RTP over UDP)."""

    def __init__(self) -> None:
        exe = shutil.which("rtsp-server-perl")
        if exe is None:
            sys.exit(
                "--transport rtsp needs Debian's rtsp-server-perl: apt-get install rtsp-server-perl"
            )
        self.client_port, self.source_port = free_port(), free_port()
        cmd = [exe, "--clientport", str(self.client_port), "--serverport", str(self.source_port)]
        cmd += ["--client_listen_address", "127.0.0.1", "--source_listen_address", "127.0.0.1"]
        cmd += ["--rtp_start_port", str(random.Random().randrange(20_000, 40_000, 2))]
        self.proc = subprocess.Popen(
            [*cmd, "--loglevel", "1"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
        )
        deadline = time.monotonic() + 10
        while not _listening(self.source_port):
            if self.proc.poll() is not None or time.monotonic() > deadline:
                sys.exit("rtsp-server-perl did not start")
            time.sleep(0.1)

    def url(self, name: str) -> str:
        return f"rtsp://127.0.0.1:{self.client_port}/{name}"

    def push_url(self, name: str) -> str:
        return f"rtsp://127.0.0.1:{self.source_port}/{name}"

    def close(self) -> None:
        self.proc.kill()
        self.proc.wait()


def _listening(port: int) -> bool:
    import socket

    with socket.socket() as s:
        return s.connect_ex(("127.0.0.1", port)) == 0


class Streams:
    """The 4 cameras' ffmpeg servers, each started again when it ends: a good camera's on its
    looped stream, a fuzzed camera's on its next spoilt copy (counted, with what was done)."""

    def __init__(
        self,
        good: dict[str, Path],
        fuzzed: dict[str, Path],
        work: Path,
        rtsp: RtspServer | None = None,
    ) -> None:
        self.ports = {n: free_port() for n in [*good, *fuzzed]}
        self.good, self.fuzzed, self.work, self.rtsp = good, fuzzed, work, rtsp
        self.served: dict[str, list[str]] = {n: [] for n in fuzzed}
        self.restarted: dict[str, int] = dict.fromkeys(good, 0)
        self.rng = random.Random(0)
        self._procs: dict[str, subprocess.Popen] = {}
        self._ended: dict[str, float] = {}  # a fuzzed camera's: when its copy's server ended
        self.held: dict[str, float] = {}  # a good camera's server not started again before
        self.started_at: dict[str, float] = {}  # each camera's server: when last started
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._keep, daemon=True)

    def url(self, name: str) -> str:
        """Where serve reads the camera."""
        if self.rtsp is not None:
            return self.rtsp.url(name)
        return f"http://127.0.0.1:{self.ports[name]}/{name}.ts"

    def _to(self, name: str) -> str:
        """Where the camera's ffmpeg plays to."""
        return self.rtsp.push_url(name) if self.rtsp is not None else self.url(name)

    def _start(self, name: str) -> None:
        self.started_at[name] = time.monotonic()
        if name in self.good:
            self._procs[name] = _server(self.good[name], self._to(name), loop=True)
            return
        k = len(self.served[name])
        data, what = spoil(self.fuzzed[name].read_bytes(), k, self.rng)
        path = self.work / f"{name}_spoilt.ts"
        path.write_bytes(data)  # the previous copy's server has ended: it no longer reads it
        self.served[name].append(what)
        self._procs[name] = _server(path, self._to(name), loop=False)

    def start(self) -> None:
        for name in self.ports:
            self._start(name)
        self._thread.start()

    def _keep(self) -> None:
        while not self._stop.wait(0.2):
            now = time.monotonic()
            for name, proc in list(self._procs.items()):
                if proc.poll() is None:
                    continue
                if name in self.restarted:
                    if now < self.held.get(name, 0.0):
                        continue  # kept away a while (benchmarks/decoder_faults.py)
                    self.restarted[name] += 1
                elif now < self._ended.setdefault(name, now) + GAP_S:
                    continue  # a fuzzed camera's stream stays away a while
                self._ended.pop(name, None)
                self._start(name)

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5)
        for proc in self._procs.values():
            proc.kill()
            proc.wait()


def _scaled_rig(calib: Path, size: tuple[int, int]) -> Rig:
    """The demo's calibration for its frames shrunk to `size` (w, h)."""
    rig = load_calibration(calib)
    out = []
    for cam in rig:
        s = size[0] / cam.size[0]
        k = cam.matrix.copy()
        k[:2] *= s
        out.append(dataclasses.replace(cam, size=(float(size[0]), float(size[1])), matrix=k))
    return Rig(tuple(out))


def _memory(proc: psutil.Process) -> tuple[float, float]:
    """Resident MB of serve itself, and of its decoder processes together."""
    own = proc.memory_info().rss / 2**20
    children = 0.0
    for child in proc.children(recursive=True):
        with contextlib.suppress(psutil.Error):  # ended meanwhile
            children += child.memory_info().rss / 2**20
    return own, children


def _events(db: Path) -> list[tuple[str, str | None]]:
    try:
        return [(e["type"], e["camera"]) for e in query_events(db)]
    except StereoposeError:  # not made: no event at all
        return []


def serve_config(work: Path, streams: Streams, videos: list[Path]) -> tuple[Path, Path]:
    """serve's configuration (and its output folder) for the demo's cameras read from
    `streams` at SUB_SIZE: the calibration scaled to match, the demo's site, no clips, cameras
    down after 1 s of silence."""
    calib = work / "calib.toml"
    save_calibration(
        calib, _scaled_rig(videos[0].parents[1] / "calibration" / "Calib.qca.txt", SUB_SIZE)
    )
    site = Path(str(resources.files("stereopose") / "data" / "demo_site.toml"))
    out = work / "data"
    cameras = "".join(
        f'[[cameras]]\nname = "{n}"\nsource = "{streams.url(n)}"\n\n' for n in sorted(streams.ports)
    )
    config = work / "serve.toml"
    config.write_text(
        f'calibration = "{calib}"\nsite = "{site}"\noutput = "{out}"\n\n'
        "[storage]\nclips = false\n\n"
        f"[serve]\nport = {free_port()}\ncamera_timeout_s = 1\nstatus_interval_s = 1\n\n"
        f"{cameras}"
    )
    return config, out


def start_serve(config: Path, log: Path, env: dict[str, str] | None = None) -> subprocess.Popen:
    """`stereopose serve config` as a child process, its output to `log`."""
    with open(log, "wb") as f:
        return subprocess.Popen(
            [sys.executable, "-m", "stereopose.cli", "serve", str(config)],
            stdout=f,
            stderr=subprocess.STDOUT,
            env=dict(os.environ, PYTHONUNBUFFERED="1", **(env or {})),
        )


def run(seconds: float, work: Path, keep_log: Path | None = None, transport: str = "http") -> dict:
    videos = demo_videos()
    subs = {v.stem: substream(v, work / f"{v.stem}_sub.mp4") for v in videos}
    good = {n: p for n, p in subs.items() if n not in FUZZED}
    fuzzed = {n: _ts(subs[n], work / f"{n}_{codec}.ts", codec) for n, codec in FUZZED.items()}
    rtsp = RtspServer() if transport == "rtsp" else None
    streams = Streams(good, fuzzed, work, rtsp)
    config, out = serve_config(work, streams, videos)
    log = work / "serve.log"

    streams.start()
    samples = []
    proc = start_serve(config, log, _capture_options(transport))
    ps = psutil.Process(proc.pid)
    t0 = time.monotonic()
    try:
        while time.monotonic() - t0 < seconds and proc.poll() is None:
            time.sleep(1.0)
            try:
                frames = int(json.loads((out / "status.json").read_text())["frames"])
            except (OSError, ValueError, KeyError):
                frames = 0
            try:
                own, children = _memory(ps)
            except psutil.Error:
                break
            samples.append((time.monotonic() - t0, frames, own, children))
        up = proc.poll() is None
        proc.send_signal(signal.SIGTERM)
        code = proc.wait(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
        streams.stop()
        if rtsp is not None:
            rtsp.close()
    text = log.read_text(errors="replace")
    if keep_log is not None:
        keep_log.write_text(text)
    events = _events(out / "events.sqlite")
    names = sorted(subs)

    def count(kind: str, name: str) -> int:
        return sum(1 for t, c in events if t == kind and c == name)

    def median(lo: float, hi: float, k: int) -> float:
        xs = [s[k] for s in samples if lo <= s[0] < hi]
        return float(np.median(xs)) if xs else float("nan")

    end = samples[-1][0] if samples else 0.0
    steps = samples[-1][1] if samples else 0
    return {
        "transport": transport,
        "seconds": end,
        "up_to_the_end": up,
        "exit_code": code,
        "steps": steps,
        "steps_per_s": steps / end if end else 0.0,
        "spoilt_served": {n: len(v) for n, v in streams.served.items()},
        "spoilt_kinds": streams.served,
        "good_restarted": streams.restarted,
        "camera_down": {n: count("camera_down", n) for n in names},
        "camera_up": {n: count("camera_up", n) for n in names},
        "stalls": sum(1 for t, _ in events if t == "service_stalled"),
        "decoders_died": text.count("decoder died"),
        "decoders_hung": text.count("decoder hung"),
        "decoders_over_memory": text.count("decoder over its memory"),
        "tracebacks": text.count("Traceback"),
        "rss_mb": {
            "serve_minute_2": median(60, 120, 2),
            "serve_last_minute": median(end - 60, end + 1, 2),
            "decoders_minute_2": median(60, 120, 3),
            "decoders_last_minute": median(end - 60, end + 1, 3),
        },
    }


def _capture_options(transport: str) -> dict[str, str]:
    """The environment that has OpenCV's FFmpeg take RTSP's RTP over UDP (its default is
    TCP, which this RTSP server does not offer)."""
    return {"OPENCV_FFMPEG_CAPTURE_OPTIONS": "rtsp_transport;udp"} if transport == "rtsp" else {}


def markdown(r: dict) -> list[str]:
    x = r["run"]
    rss = x["rss_mb"]
    md = [
        "# Fuzzed live streams",
        "",
        f"{r['date']}, {r['machine'].replace('one thread', 'all cores')}. `{r['command']}`: "
        f"`serve` (its defaults: each camera decoded in a process of its own) on the real "
        f"demo's 4 cameras at {SUB_SIZE[0]}x{SUB_SIZE[1]}, served live {_how(x)} by "
        f"ffmpeg; cam01 and cam02 good (H.264, looped), cam03 (H.264) and cam04 (H.265) "
        f"each a run of spoilt {COPY_S:.0f}-second copies of its stream (bits flipped at 1 in "
        "2,000, 20,000 or 200,000 bytes, or every 4th copy cut short at a random byte), "
        "each played once.",
        "",
        f"- Ran {x['seconds']:.0f} s; serve up to the end: **{x['up_to_the_end']}**, exit "
        f"{x['exit_code']} on SIGTERM; {x['steps']} steps ({x['steps_per_s']:.1f}/s); "
        f"stalls (`service_stalled`): **{x['stalls']}**; tracebacks in its log: "
        f"{x['tracebacks']}.",
        f"- Decoders restarted: {x['decoders_died']} died, {x['decoders_hung']} hung, "
        f"{x['decoders_over_memory']} over their memory.",
        f"- Resident memory, median of the 2nd minute -> of the last: serve "
        f"{rss['serve_minute_2']:.0f} -> {rss['serve_last_minute']:.0f} MB, its decoders "
        f"together {rss['decoders_minute_2']:.0f} -> {rss['decoders_last_minute']:.0f} MB.",
        "",
        "| camera | stream | spoilt copies served | camera_down | camera_up |",
        "|---|---|---|---|---|",
    ]
    for name in sorted(x["camera_down"]):
        kind = FUZZED.get(name)
        what = f"spoilt {'H.265' if kind == 'hevc' else 'H.264'}" if kind else "good H.264"
        served = x["spoilt_served"].get(name, "-")
        if not kind:
            served = f"- (its server restarted {x['good_restarted'].get(name, 0)} times)"
        md.append(
            f"| {name} | {what} | {served} | {x['camera_down'][name]} | {x['camera_up'][name]} |"
        )
    return md


def _how(x: dict) -> str:
    if x.get("transport", "http") == "rtsp":
        return (
            "over RTSP (each camera's ffmpeg pushing RTP to Debian's rtsp-server-perl; serve "
            "reading RTP over UDP)"
        )
    return "over HTTP (MPEG-TS)"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=600.0)
    ap.add_argument("--name", default="fuzzed_streams", help="the results' file name")
    ap.add_argument("--log", type=Path, help="keep serve's log here")
    ap.add_argument("--transport", choices=("http", "rtsp"), default="http")
    args = ap.parse_args()
    if len(demo_videos()) != 4:
        sys.exit("the demo videos are not in the cache: run `stereopose demo` once")
    with tempfile.TemporaryDirectory() as tmp:
        result = run(args.seconds, Path(tmp), args.log, args.transport)
    r = {
        "date": datetime.date.today().isoformat(),
        "machine": machine(),
        "command": " ".join(["python benchmarks/fuzzed_streams.py", *sys.argv[1:]]),
        "run": result,
    }
    save(args.name, r, markdown(r))


if __name__ == "__main__":
    main()
