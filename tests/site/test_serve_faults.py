"""`stereopose serve` under faults, as a process on small real parts: two live HTTP cameras
(ffmpeg), a real Mosquitto broker and a local webhook receiver. A camera killed and restored
gives camera_down then camera_up in SQLite, on MQTT and at the webhook; a broker down at start
gets every event once it is up; a camera that never delivers is reported, not waited for;
retention deletes old segments and clips and never the newest; SIGINT exits 0."""

from __future__ import annotations

import dataclasses
import gzip
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from brokers import Broker, Subscriber
from brokers import free_port as free_tcp_port
from receivers import Receiver
from stereopose.calibration.formats import save_calibration
from stereopose.errors import StereoposeError
from stereopose.io.sinks.events import query_events
from stereopose.sim import simulate
from stereopose.types import Rig
from streams import serve as serve_stream
from streams import served_until, wait_serving, write_video
from streams import stop as stop_streams
from waiting import wait_until

pytestmark = [pytest.mark.slow]

SIZE = (96, 64)
CAMERA_TYPES = ("camera_down", "camera_up")


def _calibration(folder: Path) -> tuple[Path, list[str]]:
    """Two simulated cameras, their image size that of the test videos."""
    scene = simulate(num_cameras=2, num_people=1, num_frames=2, seed=1, difficulty="easy")
    cams = [dataclasses.replace(c, size=SIZE) for c in scene.rig.cameras]
    path = folder / "calib.toml"
    save_calibration(path, Rig(tuple(cams)))
    return path, [c.name for c in cams]


def _config(folder: Path, calib: Path, cameras: dict[str, str], extra: str) -> Path:
    cams = "".join(f'[[cameras]]\nname = "{n}"\nsource = "{s}"\n\n' for n, s in cameras.items())
    path = folder / "serve.toml"
    path.write_text(
        f'calibration = "{calib}"\noutput = "{folder / "data"}"\n\n'
        "[detector]\nimgsz = 320\n\n[input]\ndetect_fps = 5\n\n"
        f"{extra}\n\n{cams}"
    )
    return path


def _start(config: Path, log: Path) -> subprocess.Popen:
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    with open(log, "ab") as f:
        return subprocess.Popen(
            [sys.executable, "-m", "stereopose.cli", "serve", str(config)],
            stdout=f,
            stderr=subprocess.STDOUT,
            env=env,
        )


def _stop(proc: subprocess.Popen, log: Path, sig: int = signal.SIGINT) -> int:
    proc.send_signal(sig)
    try:
        return proc.wait(timeout=40)
    except subprocess.TimeoutExpired:
        proc.kill()
        pytest.fail(f"serve did not stop within 40 s of signal {sig}:\n{log.read_text()}")


def _camera_events(db: Path) -> list[tuple[str, str]]:
    try:
        events = query_events(db)
    except StereoposeError:  # not made yet, or its tables not yet
        return []
    return [(e["type"], e["camera"]) for e in events if e["type"] in CAMERA_TYPES]


def _payloads(items) -> list[tuple[str, str]]:
    return [(e["type"], e["camera"]) for e in items if e.get("type") in CAMERA_TYPES]


def test_camera_killed_and_restored_broker_late_events_everywhere_sigint_exits_0(tmp_path):
    calib, names = _calibration(tmp_path)
    video = write_video(tmp_path / "grey.mp4", 50, 25.0, SIZE)
    ports = [free_tcp_port() for _ in names]
    servers = [serve_stream(video, p, n) for p, n in zip(ports, names, strict=True)]
    wait_serving(servers, ports)
    broker = Broker(tmp_path / "broker").start()
    sub = Subscriber(broker.port, "stereopose/t/events", session="faults-test")
    broker.stop()  # down when the service starts; the subscriber's session is kept
    receiver = Receiver()
    urls = {n: f"http://127.0.0.1:{p}/{n}.ts" for n, p in zip(names, ports, strict=True)}
    extra = (
        f'[outputs]\nwebhook = "{receiver.url}"\n\n[mqtt]\nhost = "127.0.0.1"\n'
        f'port = {broker.port}\nsite = "t"\n\n[storage]\nclips = false\n\n'
        f"[serve]\nport = {free_tcp_port()}\ncamera_timeout_s = 1\n"
        "status_interval_s = 1\n"
    )
    config = _config(tmp_path, calib, urls, extra)
    log, db = tmp_path / "serve.log", tmp_path / "data" / "events.sqlite"
    proc = _start(config, log)
    try:
        status = tmp_path / "data" / "status.json"
        wait_until(
            lambda: (
                status.exists()
                and all(
                    c["state"] == "up" for c in json.loads(status.read_text())["cameras"].values()
                )
            ),
            "both cameras up",
            timeout_s=60,
            poll_s=0.2,
        )
        stop_streams(servers[1:])
        down = [("camera_down", names[1])]
        wait_until(lambda: _camera_events(db) == down, "camera_down", timeout_s=30)
        servers[1] = served_until(
            lambda: serve_stream(video, ports[1], names[1]),
            lambda: _camera_events(db) == [*down, ("camera_up", names[1])],
            "camera_up",
            timeout_s=60,
        )
        broker.start()
        logged = _camera_events(db)
        wait_until(
            lambda: _payloads(json.loads(p) for p in sub.on("stereopose/t/events")) == logged,
            "the events on MQTT",
            timeout_s=30,
        )
        wait_until(lambda: _payloads(receiver.bodies) == logged, "the events at the webhook")
    finally:
        rc = _stop(proc, log)
        stop_streams(servers)
        sub.close()
        receiver.close()
        broker.stop()
    assert rc == 0, log.read_text()
    assert _camera_events(db) == logged  # nothing more came after the stop
    assert "Traceback" not in log.read_text()


def _old(path: Path, size: int, age_s: float) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(b"x" * size)
    then = time.time() - age_s
    os.utime(path, (then, then))
    return path


def test_blind_camera_reported_and_retention_keeps_the_newest(tmp_path):
    calib, names = _calibration(tmp_path)
    video = write_video(tmp_path / "grey.mp4", 50, 25.0, SIZE)
    data = tmp_path / "data"
    day = 86400.0
    stale_segment = _old(data / "poses" / "20000101T000000Z.jsonl.gz", 10, 10 * day)
    stale_clip = _old(data / "clips" / "20000101-000000_cam_enter.mp4", 10, 3 * day)
    big_clip = _old(data / "clips" / "20000102-000000_cam_enter.mp4", 5000, 60.0)
    extra = (
        "[storage]\nsegment_s = 1\nmax_gb = 0.0000002\nclip_retention_days = 1\n"
        "maintenance_interval_s = 0.3\n\n"
        f"[serve]\nport = {free_tcp_port()}\ncamera_timeout_s = 1\n"
        "status_interval_s = 0.5\n"
    )
    # one camera a looped file, the other a port nothing answers on: live and recorded may
    # not be mixed, so both are live, the blind one refused
    port = free_tcp_port()
    server = serve_stream(video, port, names[0])
    wait_serving([server], [port])
    urls = {
        names[0]: f"http://127.0.0.1:{port}/{names[0]}.ts",
        names[1]: f"http://127.0.0.1:{free_tcp_port()}/{names[1]}.ts",
    }
    config = _config(tmp_path, calib, urls, extra)
    log, db = tmp_path / "serve.log", data / "events.sqlite"
    proc = _start(config, log)
    seen: set[str] = set()

    def segments() -> list[Path]:
        found = sorted((data / "poses").glob("*.jsonl.gz"))
        seen.update(p.name for p in found)
        return found

    try:
        wait_until(
            lambda: ("camera_down", names[1]) in _camera_events(db),
            "the blind camera reported",
            timeout_s=60,
            poll_s=0.2,
        )
        wait_until(
            lambda: (
                not stale_segment.exists() and not stale_clip.exists() and not big_clip.exists()
            ),
            "old files deleted",
            timeout_s=30,
        )

        def capped() -> bool:
            kept = {p.name for p in segments()}
            return bool(kept) and bool(seen - kept - {stale_segment.name})

        wait_until(capped, "a segment of this run deleted by the cap", timeout_s=60, poll_s=0.1)
        kept = segments()
        assert kept and kept[-1].name == max(seen)  # never the newest
    finally:
        rc = _stop(proc, log, signal.SIGTERM)
        stop_streams([server])
    assert rc == 0, log.read_text()
    assert ("camera_up", names[1]) not in _camera_events(db)
    health = json.loads((data / "status.json").read_text())
    assert health["cameras"][names[1]]["state"] == "down"
    newest = sorted((data / "poses").glob("*.jsonl.gz"))[-1]
    assert all(
        "frame" in json.loads(line)
        for line in gzip.decompress(newest.read_bytes()).decode().splitlines()
    )
    assert "Traceback" not in log.read_text()
