"""`stereopose serve` as a process started by hand (umask 022, not the systemd unit), with
two looped recorded cameras and an MQTT broker that is down at first: its data folder holds
only private files (0600) and folders (0700), also those an earlier run left readable; its
health is degraded by the broker outage, naming it, and ok once the broker is up; a request
for a foreign Host is refused while the server's own names are served."""

from __future__ import annotations

import dataclasses
import http.client
import json
import os
import signal
import stat
import subprocess
import sys
from pathlib import Path

import pytest

from brokers import Broker
from brokers import free_port as free_tcp_port
from stereopose.calibration.formats import save_calibration
from stereopose.sim import simulate
from stereopose.types import Rig
from streams import write_video
from waiting import wait_until

pytestmark = [pytest.mark.slow]

SIZE = (96, 64)


def _calibration(folder: Path) -> tuple[Path, list[str]]:
    scene = simulate(num_cameras=2, num_people=1, num_frames=2, seed=1, difficulty="easy")
    cams = [dataclasses.replace(c, size=SIZE) for c in scene.rig.cameras]
    path = folder / "calib.toml"
    save_calibration(path, Rig(tuple(cams)))
    return path, [c.name for c in cams]


def _health(port: int, host: str | None = None) -> tuple[int, dict]:
    """GET /api/health on 127.0.0.1:port with this Host header (None: 127.0.0.1:port)."""
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=10)
    try:
        conn.putrequest("GET", "/api/health", skip_host=True)
        conn.putheader("Host", host or f"127.0.0.1:{port}")
        conn.endheaders()
        resp = conn.getresponse()
        return resp.status, json.loads(resp.read() or b"{}")
    except (OSError, http.client.HTTPException, ValueError):
        return 0, {}
    finally:
        conn.close()


def _public(root: Path) -> list[str]:
    """Every file and folder under root (root too) that group or others may use."""
    paths = [root, *root.rglob("*")]
    return [
        f"{p} {stat.filemode(p.lstat().st_mode)}"
        for p in paths
        if not p.is_symlink() and p.lstat().st_mode & 0o077
    ]


def test_serve_by_hand_keeps_its_data_private_and_reports_the_broker_outage(tmp_path):
    calib, names = _calibration(tmp_path)
    video = write_video(tmp_path / "grey.mp4", 50, 25.0, SIZE)
    data = tmp_path / "data"
    (data / "poses").mkdir(parents=True)
    old = data / "notes-of-an-earlier-run.txt"
    old.write_text("world-readable\n")
    os.chmod(old, 0o644)
    os.chmod(data / "poses", 0o755)
    broker = Broker(tmp_path / "broker")  # not started: the outage
    port = free_tcp_port()
    cams = "".join(f'[[cameras]]\nname = "{n}"\nsource = "{video}"\nloop = true\n\n' for n in names)
    config = tmp_path / "serve.toml"
    config.write_text(
        f'calibration = "{calib}"\noutput = "{data}"\n\n'
        "[detector]\nimgsz = 320\n\n[input]\ndetect_fps = 5\n\n"
        f'[mqtt]\nhost = "127.0.0.1"\nport = {broker.port}\nsite = "t"\n'
        "\n"
        f"[serve]\nport = {port}\nstatus_interval_s = 0.5\n"
        'allowed_hosts = ["scada.example.org"]\n\n'
        f"{cams}"
    )
    log = tmp_path / "serve.log"
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    with open(log, "ab") as f:
        proc = subprocess.Popen(
            [sys.executable, "-m", "stereopose.cli", "serve", str(config)],
            stdout=f,
            stderr=subprocess.STDOUT,
            env=env,
            preexec_fn=lambda: os.umask(0o022),
        )
    try:

        def outage() -> bool:
            if proc.poll() is not None:
                pytest.fail(f"serve ended:\n{log.read_text()}")
            status, h = _health(port)
            return status == 200 and any(
                p.startswith("output mqtt failing: broker") for p in h.get("problems", ())
            )

        wait_until(outage, "health degraded by the broker outage", timeout_s=90, poll_s=0.2)
        h = _health(port)[1]
        assert h["status"] == "degraded" and h["outputs"]["mqtt"]["state"] == "down"
        assert h["version"] is None  # anonymous
        assert _health(port, "attacker.example.com")[0] == 421
        assert _health(port, f"scada.example.org:{port}")[0] == 200
        assert _health(port, f"localhost:{port}")[0] == 200
        broker.start()
        wait_until(
            lambda: _health(port)[1].get("outputs", {}).get("mqtt", {}).get("state") == "up",
            "the broker's output up",
            timeout_s=30,
            poll_s=0.2,
        )
        h = _health(port)[1]
        assert not [p for p in h["problems"] if p.startswith("output")], h
        wait_until(
            lambda: (
                (data / "status.json").exists()
                and (data / "events.sqlite").exists()
                and any((data / "poses").glob("*.jsonl.gz"))
            ),
            "the service's files",
            timeout_s=30,
            poll_s=0.2,
        )
        assert _public(data) == []  # while it runs: the log's -wal and -shm too
    finally:
        proc.send_signal(signal.SIGINT)
        try:
            rc = proc.wait(timeout=40)
        except subprocess.TimeoutExpired:
            proc.kill()
            pytest.fail(f"serve did not stop within 40 s:\n{log.read_text()}")
        broker.stop()
    assert rc == 0, log.read_text()
    assert _public(data) == []
    assert (data / "status.json").is_file() and old.read_text() == "world-readable\n"
    assert "Traceback" not in log.read_text()
