"""Two detection nodes and one fusion service, as real processes on a real broker: the
demo's four cameras over two nodes, a node killed and started again, the broker restarted."""

from __future__ import annotations

import json
import os
import signal
import sqlite3
import subprocess
import sys
from pathlib import Path

import pytest

from brokers import Broker, Subscriber, free_port
from stereopose.nodes.hold import decode_hold
from waiting import http_get, wait_until

ENV = dict(os.environ, PYTHONUNBUFFERED="1", PYTHONDONTWRITEBYTECODE="1", STEREOPOSE_THREADS="1")


def _config(tmp_path: Path, broker_port: int, http_port: int) -> Path:
    from stereopose.pipeline.demo import write_serve_demo_config

    path = write_serve_demo_config(tmp_path / "demo", tmp_path / "data", http_port, detect_fps=2.0)
    text = (
        path.read_text()
        .replace(
            "[serve]\n",
            f'[mqtt]\nhost = "127.0.0.1"\nport = {broker_port}\nsite = "north"\n\n[serve]\n',
            1,
        )
        .replace("[input]\n", '[input]\ndetection = "nodes"\n', 1)
    )
    text += (
        '[[nodes]]\nname = "node-a"\ncameras = ["cam01", "cam02"]\n\n'
        '[[nodes]]\nname = "node-b"\ncameras = ["cam03", "cam04"]\n'
    )
    path.write_text(text)
    return path


def _start(tmp_path: Path, name: str, *args: str) -> subprocess.Popen:
    with open(tmp_path / f"{name}.log", "ab") as f:
        return subprocess.Popen(
            [sys.executable, "-m", "stereopose.cli", *args],
            stdout=f,
            stderr=subprocess.STDOUT,
            env=ENV,
        )


def _stop(proc: subprocess.Popen) -> int | None:
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            return proc.wait(30)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
            return None
    return proc.returncode


@pytest.mark.slow
@pytest.mark.realdata
def test_two_nodes_feed_one_service_and_a_killed_node_takes_its_cameras_down(tmp_path):
    broker = Broker(tmp_path / "broker").start()
    http_port = free_port()
    config = _config(tmp_path, broker.port, http_port)
    db = tmp_path / "data" / "events.sqlite"
    health_url = f"http://127.0.0.1:{http_port}/api/health"

    def health() -> dict:
        status, body = http_get(health_url)
        return json.loads(body) if status == 200 else {}

    def states() -> dict[str, str]:
        return {n: c["state"] for n, c in health().get("cameras", {}).items()}

    def events(kind: str) -> list[tuple]:
        if not db.exists():
            return []
        con = sqlite3.connect(f"file:{db}?mode=ro", uri=True, timeout=5)
        try:
            rows = "SELECT type, camera FROM events WHERE kind = ? ORDER BY id"
            return con.execute(rows, (kind,)).fetchall()
        except sqlite3.OperationalError:  # its tables not yet made
            return []
        finally:
            con.close()

    def frames(name: str) -> int:
        return health().get("cameras", {}).get(name, {}).get("frames", 0)

    serve = _start(tmp_path, "serve", "serve", str(config))
    nodes = {
        n: _start(tmp_path, n, "detect-node", str(config), "--node", n)
        for n in ("node-a", "node-b")
    }
    watcher = Subscriber(broker.port, "stereopose/north/nodes/+", "stereopose/north/hold")
    try:
        all_up = {f"cam0{i}": "up" for i in range(1, 5)}
        wait_until(lambda: states() == all_up, "the four cameras up in /api/health", 180, 0.5)
        wait_until(lambda: health().get("people", 0) >= 1, "people tracked", 60, 0.5)
        wait_until(lambda: any(k == "energized" for k, _ in _kinds(db)), "a zone event", 120, 0.5)

        def nodes_report() -> dict:  # status.json, written every status_interval_s
            return json.loads((tmp_path / "data" / "status.json").read_text())["nodes"]

        wait_until(
            lambda: nodes_report()["cameras"]["cam04"]["node"] is not None,
            "the nodes in status.json",
            30,
            0.5,
        )
        report = nodes_report()
        # the alarms' clips, made of the nodes' pictures
        clips = tmp_path / "data" / "clips"
        wait_until(lambda: any(clips.rglob("*.mp4")), "an alarm's clip", 60, 0.5)
        assert set(report["nodes"]) == {"node-a", "node-b"}
        assert report["cameras"]["cam01"]["node"] == "node-a"
        assert report["cameras"]["cam04"]["node"] == "node-b"
        assert report["nodes"]["node-a"]["clock_refused"] is False
        # the service tells the nodes which cameras see the walker at the busbar (never
        # carried there), and the nodes say what they carried
        holds = [decode_hold(p.encode()) for p in watcher.on("stereopose/north/hold")]
        assert holds and any(held for _, held, _ in holds), holds[-5:]
        assert all(held <= set(all_up) for _, held, _ in holds)
        said = json.loads(watcher.on("stereopose/north/nodes/node-b")[-1])
        assert said["carry"]["holds"]["taken"] > 0 and said["carry"]["holds"]["malformed"] == 0
        # each camera's light as its node sees it, in the service's /metrics (the console's too)
        metrics = f"http://127.0.0.1:{http_port}/metrics"
        day = 'stereopose_camera_light{camera="%s",mode="day"} 1.0'
        wait_until(
            lambda: all(day % c in http_get(metrics)[1].decode() for c in all_up),
            "the nodes' cameras' light in /metrics",
            30,
            0.5,
        )

        before = len(events("camera"))  # a node slower to start than the timeout: its own
        nodes["node-a"].send_signal(signal.SIGKILL)  # no goodbye: its will says offline
        nodes["node-a"].wait(10)
        wait_until(
            lambda: states() == all_up | {"cam01": "down", "cam02": "down"},
            "node-a's two cameras down, node-b's up",
            20,
            0.2,
        )
        # their events come with the service's next step, stored in its transaction
        down = [("camera_down", "cam01"), ("camera_down", "cam02")]
        wait_until(
            lambda: sorted(events("camera")[before:]) == down,
            "node-a's two camera_down events in the log",
            20,
            0.2,
        )
        assert any('"offline"' in p for p in watcher.on("stereopose/north/nodes/node-a"))

        nodes["node-a"] = _start(tmp_path, "node-a", "detect-node", str(config), "--node", "node-a")
        wait_until(lambda: states() == all_up, "node-a's cameras back up", 120, 0.5)
        assert sorted(events("camera")[before + 2 :]) == [
            ("camera_up", "cam01"),
            ("camera_up", "cam02"),
        ]

        broker.restart()  # both sides connect again by themselves
        seen = {n: frames(n) for n in all_up}
        wait_until(
            lambda: all(frames(n) > seen[n] + 4 for n in all_up) and states() == all_up,
            "every camera delivering after the broker's restart",
            90,
            0.5,
        )
    finally:
        watcher.close()
        codes = {n: _stop(p) for n, p in nodes.items()}
        served = _stop(serve)
        broker.stop()
    assert codes == {"node-a": 0, "node-b": 0}, (tmp_path / "node-a.log").read_text()[-2000:]
    assert served == 0, (tmp_path / "serve.log").read_text()[-3000:]
    log = (tmp_path / "serve.log").read_text()
    assert "Traceback" not in log


def _kinds(db: Path) -> list[tuple]:
    if not db.exists():
        return []
    con = sqlite3.connect(f"file:{db}?mode=ro", uri=True, timeout=5)
    try:
        return con.execute("SELECT kind, type FROM events").fetchall()
    except sqlite3.OperationalError:
        return []
    finally:
        con.close()
