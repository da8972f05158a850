"""`serve` with each live camera decoded in a process of its own ([input] decoders =
"process"), two real HTTP cameras (ffmpeg): one camera's decoder killed with SIGSEGV mid-run is
that camera down at once and up again once its stream is, while the other camera keeps
stepping with no stall, and the service stays up."""

from __future__ import annotations

import dataclasses
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from brokers import free_port as free_tcp_port
from stereopose.calibration.formats import save_calibration
from stereopose.errors import StereoposeError
from stereopose.io.sinks.events import query_events
from stereopose.sim import simulate
from stereopose.types import Rig
from streams import serve as serve_stream
from streams import stop as stop_streams
from streams import wait_serving, write_video
from waiting import wait_until

pytestmark = [pytest.mark.slow]

SIZE = (96, 64)


def _events(db: Path) -> list[tuple[str, str | None]]:
    try:
        return [(e["type"], e["camera"]) for e in query_events(db)]
    except StereoposeError:  # not made yet
        return []


def _decoders(pid: int) -> list[int]:
    """serve's decoder processes (multiprocessing's spawned children)."""
    out = []
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            ppid = int((d / "stat").read_text().rsplit(")", 1)[1].split()[1])
            cmd = (d / "cmdline").read_bytes()
        except (OSError, IndexError, ValueError):
            continue
        if ppid == pid and b"spawn_main" in cmd:
            out.append(int(d.name))
    return out


def test_a_decoder_killed_mid_run_is_its_camera_down_then_up_and_nothing_else(tmp_path):
    scene = simulate(num_cameras=2, num_people=1, num_frames=2, seed=1, difficulty="easy")
    cams = [dataclasses.replace(c, size=SIZE) for c in scene.rig.cameras]
    calib = tmp_path / "calib.toml"
    save_calibration(calib, Rig(tuple(cams)))
    names = [c.name for c in cams]
    video = write_video(tmp_path / "grey.mp4", 50, 25.0, SIZE)
    ports = [free_tcp_port() for _ in names]
    servers = [serve_stream(video, p, n) for p, n in zip(ports, names, strict=True)]
    proc = None
    log, db = tmp_path / "serve.log", tmp_path / "data" / "events.sqlite"
    try:
        wait_serving(servers, ports)
        sources = "".join(
            f'[[cameras]]\nname = "{n}"\nsource = "http://127.0.0.1:{p}/{n}.ts"\n\n'
            for n, p in zip(names, ports, strict=True)
        )
        config = tmp_path / "serve.toml"
        config.write_text(
            f'calibration = "{calib}"\noutput = "{tmp_path / "data"}"\n\n'
            '[detector]\nimgsz = 320\n\n[input]\ndetect_fps = 5\ndecoders = "process"\n\n'
            "[storage]\nclips = false\n\n"
            f"[serve]\nport = {free_tcp_port()}\ncamera_timeout_s = 1\nstatus_interval_s = 0.5\n\n"
            f"{sources}"
        )
        with open(log, "wb") as f:
            proc = subprocess.Popen(
                [sys.executable, "-m", "stereopose.cli", "serve", str(config)],
                stdout=f,
                stderr=subprocess.STDOUT,
                env=dict(os.environ, PYTHONUNBUFFERED="1"),
            )
        status = tmp_path / "data" / "status.json"

        def steps() -> int:
            try:
                return int(json.loads(status.read_text())["frames"])
            except (OSError, ValueError, KeyError):
                return 0

        def both_up() -> bool:
            try:
                doc = json.loads(status.read_text())
            except (OSError, ValueError):
                return False
            return all(c["state"] == "up" for c in doc["cameras"].values())

        wait_until(both_up, "both cameras up", timeout_s=90, poll_s=0.2)
        decoders = wait_until(
            lambda: len(_decoders(proc.pid)) == 2 and _decoders(proc.pid),
            "two decoder processes",
            timeout_s=10,
        )
        os.kill(decoders[0], signal.SIGSEGV)
        killed = time.monotonic()
        down = wait_until(
            lambda: [e for e in _events(db) if e[0] == "camera_down"],
            "a camera down",
            timeout_s=10,
            poll_s=0.05,
        )
        down_s = time.monotonic() - killed
        assert len(down) == 1, down
        bad = down[0][1]
        stepped = steps()
        wait_until(lambda: steps() >= stepped + 5, "steps go on", timeout_s=20, poll_s=0.2)
        # its server served one client: started again, the stream is good again
        k = names.index(bad)
        stop_streams([servers[k]])
        servers[k] = serve_stream(video, ports[k], bad)
        wait_serving([servers[k]], [ports[k]])
        good_again = time.monotonic()
        wait_until(lambda: ("camera_up", bad) in _events(db), "the camera up", timeout_s=30)
        up_s = time.monotonic() - good_again
        assert proc.poll() is None, log.read_text()
        types = [t for t, _ in _events(db)]
        assert "service_stalled" not in types, types
        assert [c for t, c in _events(db) if t in ("camera_down", "camera_up")] == [bad, bad]
        assert down_s <= 2.0, down_s
        assert up_s <= 10.0, up_s
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=40) == 0, log.read_text()
        text = log.read_text()
        assert "decoder died: killed by" in text and "SIGSEGV" in text, text
        assert "Traceback" not in text, text
    finally:
        if proc is not None and proc.poll() is None:
            proc.kill()
        stop_streams(servers)
