"""`stereopose serve` on the looped real demo, as a process, seen through the console's API:
a user added with the users command logs in; the people of the demo are on /api/people and
move; each camera's snapshot is a JPEG with the demo's picture; events come on /api/events
and on the live channel; `serve` prints the console's address; SIGTERM still exits 0."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import cv2
import httpx
import numpy as np
import pytest

from brokers import free_port
from stereopose.pipeline.demo import write_serve_demo_config
from waiting import wait_until

pytestmark = [pytest.mark.realdata, pytest.mark.slow]


def _ok(client: httpx.Client, path: str) -> bool:
    try:
        return client.get(path).status_code == 200
    except httpx.HTTPError:
        return False


def test_serve_demo_through_the_console(tmp_path):
    port = free_port()
    config = write_serve_demo_config(tmp_path / "demo", tmp_path / "data", port, imgsz=320)
    env = dict(os.environ, PYTHONUNBUFFERED="1", PYTHONDONTWRITEBYTECODE="1")
    add = subprocess.run(
        [
            sys.executable,
            "-m",
            "stereopose.cli",
            "users",
            "add",
            "olga",
            "--role",
            "operator",
            "--config",
            str(config),
        ],
        input="olga-password\n",
        text=True,
        capture_output=True,
        env=env,
        timeout=60,
    )
    assert add.returncode == 0, add.stderr
    log = tmp_path / "serve.log"
    with open(log, "wb") as f:
        proc = subprocess.Popen(
            [sys.executable, "-m", "stereopose.cli", "serve", str(config)],
            stdout=f,
            stderr=subprocess.STDOUT,
            env=env,
        )
    base = f"http://127.0.0.1:{port}"
    try:
        c = httpx.Client(base_url=base, timeout=60)  # argon2 and a busy machine
        wait_until(
            lambda: _ok(c, "/") and _ok(c, "/console/plotly.min.js"),
            "the page",
            timeout_s=90,
            poll_s=0.2,
        )
        assert c.get("/api/people").status_code == 401
        r = c.post("/api/login", json={"username": "olga", "password": "olga-password"})
        assert r.status_code == 200 and r.json()["role"] == "operator"

        def people() -> list[dict]:
            return c.get("/api/people").json()["people"]

        wait_until(lambda: len(people()) >= 1, "the demo's people", timeout_s=90, poll_s=0.2)
        first = {p["id"]: p["position"] for p in people()}

        def moved() -> bool:
            now = {p["id"]: p["position"] for p in people()}
            return any(i in first and now[i] != first[i] for i in now)

        wait_until(moved, "a person of the first moment elsewhere", timeout_s=60, poll_s=0.2)
        for cam in c.get("/api/cameras").json()["cameras"]:
            url = cam["snapshot"]
            wait_until(lambda u=url: _ok(c, u), f"{cam['name']}'s snapshot", timeout_s=30)
            shot = c.get(url)
            assert shot.headers["content-type"] == "image/jpeg"
            picture = cv2.imdecode(np.frombuffer(shot.content, np.uint8), cv2.IMREAD_COLOR)
            assert picture is not None and picture.shape[0] > picture.shape[1] > 100
            assert picture.std() > 10  # the demo's picture, not a blank frame
        wait_until(
            lambda: c.get("/api/events").json()["events"], "events", timeout_s=90, poll_s=0.5
        )
        events = c.get("/api/events").json()["events"]
        assert all(e["wall_t"] > time.time() - 3600 for e in events)
        started = c.get("/api/health").json()["uptime_s"]
        assert started > 0
    finally:
        proc.send_signal(signal.SIGTERM)
        try:
            rc = proc.wait(timeout=40)
        except subprocess.TimeoutExpired:
            proc.kill()
            pytest.fail(f"serve did not stop within 40 s of SIGTERM:\n{log.read_text()}")
    text = log.read_text()
    assert rc == 0, text
    assert f"operator console: http://127.0.0.1:{port}/" in text
    assert "Traceback" not in text
    assert "olga-password" not in text


def test_serve_on_every_interface_without_a_user_is_refused(tmp_path):
    config = write_serve_demo_config(tmp_path / "demo", tmp_path / "data", 0, imgsz=320)
    config.write_text(config.read_text().replace('host = "127.0.0.1"', 'host = "0.0.0.0"'))
    env = dict(os.environ, PYTHONDONTWRITEBYTECODE="1")
    r = subprocess.run(
        [sys.executable, "-m", "stereopose.cli", "serve", str(config)],
        capture_output=True,
        text=True,
        timeout=120,
        env=env,
    )
    assert r.returncode == 2, r.stdout + r.stderr
    message = " ".join(r.stderr.split())
    assert "serve.host '0.0.0.0' is reachable from other machines" in message
    assert f"stereopose users add NAME --role admin --config {config}" in message
    assert "Traceback" not in r.stderr
    assert not (tmp_path / "data" / "events.sqlite").exists()  # refused before any work
