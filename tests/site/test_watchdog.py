"""systemd's notify protocol against a real datagram socket: READY=1 at the first step, the
watchdog fed only while steps advance, STOPPING=1 at the close; and a real `serve` doing so
under a notify socket as systemd would give it (Type=notify, WatchdogSec)."""

from __future__ import annotations

import dataclasses
import os
import signal
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from brokers import free_port as free_tcp_port
from stereopose.calibration.formats import save_calibration
from stereopose.io.sinks.base import FrameResult
from stereopose.sim import simulate
from stereopose.site.watchdog import Notifier, Watchdog
from stereopose.types import Rig
from streams import serve as serve_stream
from streams import stop as stop_streams
from streams import wait_serving, write_video
from waiting import wait_until


class Systemd:
    """The notify socket's other end: a bound datagram socket, its messages kept."""

    def __init__(self, folder: Path) -> None:
        self.path = folder / "notify.sock"
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self.sock.bind(str(self.path))
        self.sock.settimeout(0.05)
        self.got: list[str] = []

    def read(self) -> list[str]:
        while True:
            try:
                self.got.append(self.sock.recv(4096).decode())
            except TimeoutError:
                return self.got

    def lines(self) -> list[str]:
        return [line for m in self.read() for line in m.split("\n")]

    def close(self) -> None:
        self.sock.close()


def _step(k: int) -> FrameResult:
    return FrameResult(frame=k, t=0.1 * k, people2d={}, people3d=None, events=[])


def test_ready_at_the_first_step_fed_while_steps_advance_and_stopping_at_the_close(tmp_path):
    systemd = Systemd(tmp_path)
    now = [0.0]
    env = {"NOTIFY_SOCKET": str(systemd.path), "WATCHDOG_USEC": "2000000"}
    dog = Watchdog(Notifier(env), status=lambda: "ok", clock=lambda: now[0])
    try:
        for k in range(30):  # 3 s of steps at 10 steps/s: fed every second (half the period)
            dog.write(_step(k))
            now[0] += 0.1
        lines = systemd.lines()
        assert lines[0] == "READY=1" and lines.count("READY=1") == 1
        assert lines.count("WATCHDOG=1") == dog.fed == 3
        assert "STATUS=step 0, 0 s; ok" in lines
        now[0] += 60.0  # the loop hangs: no step, nothing fed however long
        assert "WATCHDOG=1" not in systemd.lines()[len(lines) :]
        dog.write(_step(30))  # a step again: fed at once
        assert systemd.lines()[len(lines) :][0] == "WATCHDOG=1"
        dog.close()
        dog.close()
        assert systemd.lines().count("STOPPING=1") == 1
    finally:
        systemd.close()


def test_the_environment_is_read_as_systemd_writes_it(tmp_path):
    assert not Notifier({}).enabled and Notifier({}).watchdog_s is None
    assert Notifier({"NOTIFY_SOCKET": "@stereopose"}).address == b"\0stereopose"
    assert not Notifier({"NOTIFY_SOCKET": "relative/path"}).enabled
    other = {"NOTIFY_SOCKET": "/x", "WATCHDOG_USEC": "5000000", "WATCHDOG_PID": "1"}
    assert Notifier(other).watchdog_s is None  # another process's watchdog
    assert Notifier({**other, "WATCHDOG_PID": str(os.getpid())}).watchdog_s == 5.0
    assert Notifier({"NOTIFY_SOCKET": "/x", "WATCHDOG_USEC": "soon"}).watchdog_s is None
    gone = Notifier({"NOTIFY_SOCKET": str(tmp_path / "none.sock")})
    assert not gone.send("READY=1") and not gone.send("WATCHDOG=1") and gone.failed == 2
    quiet = Watchdog(Notifier({}))  # not under systemd: nothing sent, nothing fails
    quiet.write(_step(0))
    quiet.close()
    assert not quiet.ready


SIZE = (96, 64)


@pytest.mark.slow
def test_serve_tells_systemd_it_is_ready_feeds_its_watchdog_and_stops(tmp_path):
    scene = simulate(num_cameras=2, num_people=1, num_frames=2, seed=1, difficulty="easy")
    cams = [dataclasses.replace(c, size=SIZE) for c in scene.rig.cameras]
    calib = tmp_path / "calib.toml"
    save_calibration(calib, Rig(tuple(cams)))
    video = write_video(tmp_path / "grey.mp4", 50, 25.0, SIZE)
    ports = [free_tcp_port() for _ in cams]
    servers = [serve_stream(video, p, c.name) for p, c in zip(ports, cams, strict=True)]
    systemd = Systemd(tmp_path)
    proc = None
    try:
        wait_serving(servers, ports)
        sources = "".join(
            f'[[cameras]]\nname = "{c.name}"\nsource = "http://127.0.0.1:{p}/{c.name}.ts"\n\n'
            for c, p in zip(cams, ports, strict=True)
        )
        config = tmp_path / "serve.toml"
        config.write_text(
            f'calibration = "{calib}"\noutput = "{tmp_path / "data"}"\n\n'
            "[detector]\nimgsz = 320\n\n[input]\ndetect_fps = 5\n\n[storage]\nclips = false\n\n"
            f"[serve]\nport = {free_tcp_port()}\n\n{sources}"
        )
        env = dict(os.environ, NOTIFY_SOCKET=str(systemd.path), WATCHDOG_USEC="1000000")
        log = tmp_path / "serve.log"
        with open(log, "wb") as f:
            proc = subprocess.Popen(
                [sys.executable, "-m", "stereopose.cli", "serve", str(config)],
                stdout=f,
                stderr=subprocess.STDOUT,
                env=env,
            )
        wait_until(
            lambda: systemd.lines().count("WATCHDOG=1") >= 3 or proc.poll() is not None,
            "serve's ready and three feeds of its watchdog",
            timeout_s=120,
        )
        assert proc.poll() is None, log.read_text()
        lines = systemd.lines()
        assert lines[0] == "READY=1" and lines.count("READY=1") == 1
        assert any(line.startswith("STATUS=step ") for line in lines)
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=40) == 0, log.read_text()
        assert systemd.lines()[-1] == "STOPPING=1"
    finally:
        if proc is not None and proc.poll() is None:
            proc.kill()
        systemd.close()
        stop_streams(servers)
