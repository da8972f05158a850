"""`stereopose serve` on the looped real demo, as a process: a real Mosquitto broker and a
local webhook receiver; events agree across SQLite, MQTT and the webhook; health and metrics
answer; SIGTERM ends it with exit 0, every output readable; a restart continues the ids."""

from __future__ import annotations

import gzip
import json
import os
import re
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from brokers import Broker, Subscriber, free_port
from receivers import Receiver
from stereopose.io.sinks.events import query_events
from stereopose.pipeline.demo import write_serve_demo_config
from waiting import http_get, wait_until

pytestmark = [pytest.mark.realdata, pytest.mark.slow]

ZONE_TYPES = ("enter", "exit", "approach", "dwell", "left_work_area")


def _key(e: dict) -> tuple:
    return (e["type"], e["person"], e["zone"], e["frame"])


def _start(config: Path, log: Path) -> subprocess.Popen:
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    with open(log, "ab") as f:
        return subprocess.Popen(
            [sys.executable, "-m", "stereopose.cli", "serve", str(config)],
            stdout=f,
            stderr=subprocess.STDOUT,
            env=env,
        )


def _stop(proc: subprocess.Popen, log: Path) -> int:
    proc.send_signal(signal.SIGTERM)
    try:
        return proc.wait(timeout=40)
    except subprocess.TimeoutExpired:
        proc.kill()
        pytest.fail(f"serve did not stop within 40 s of SIGTERM:\n{log.read_text()}")


@pytest.fixture
def setup(tmp_path):
    broker = Broker(tmp_path / "broker").start()
    receiver = Receiver()
    port = free_port()
    config = write_serve_demo_config(tmp_path / "demo", tmp_path / "data", port, imgsz=320)
    text = config.read_text()
    text = text.replace(
        "[serve]\n",
        f'[outputs]\nwebhook = "{receiver.url}"\n\n'
        f'[mqtt]\nhost = "127.0.0.1"\nport = {broker.port}\nsite = "demo"\n\n'
        "[storage]\nsegment_s = 60\n\n[serve]\nstatus_interval_s = 1\n",
        1,
    )
    config.write_text(text)
    sub = Subscriber(broker.port, "stereopose/demo/#")
    yield config, tmp_path / "data", port, sub, receiver, tmp_path / "serve.log"
    sub.close()
    receiver.close()
    broker.stop()


def test_serve_events_agree_health_answers_and_sigterm_exits_0(setup):
    config, data, port, sub, receiver, log = setup
    base = f"http://127.0.0.1:{port}"
    proc = _start(config, log)
    try:
        wait_until(lambda: http_get(base + "/api/health")[0] == 200, "health 200", timeout_s=90)
        db = data / "events.sqlite"
        wait_until(
            lambda: db.exists() and len(query_events(db)) >= 2,
            "events in the log",
            timeout_s=90,
            poll_s=0.5,
        )
        health = json.loads(http_get(base + "/api/health")[1])
        assert set(health["cameras"]) == {"cam01", "cam02", "cam03", "cam04"}
        assert all(c["state"] == "up" for c in health["cameras"].values())
        status, metrics = http_get(base + "/metrics")
        assert status == 200 and b"stereopose_frames_total" in metrics
        assert b'stereopose_queue_size{queue="mqtt"}' in metrics
        # detection runs on its own thread, and its time is in the stage figures all the same
        detect = re.search(rb'stereopose_stage_seconds_sum\{stage="detect"\} (\S+)', metrics)
        assert detect and float(detect.group(1)) > 0, metrics.decode()
        # detection in regions (the default): its figures per camera
        for cam in ("cam01", "cam02", "cam03", "cam04"):
            steps = re.search(
                rb'stereopose_detection_steps_total\{camera="%s"\} (\S+)' % cam.encode(), metrics
            )
            assert steps and float(steps.group(1)) > 0, metrics.decode()
        assert b"stereopose_detection_full_scans_total" in metrics

        def status() -> dict:  # rewritten every second: the first one may be the start's
            try:
                return json.loads((data / "status.json").read_text())
            except (OSError, ValueError):
                return {}

        wait_until(lambda: status().get("status") in ("ok", "degraded"), "status.json ok")
        doc = status()
        assert set(doc["regions"]) == {"cam01", "cam02", "cam03", "cam04"}
        assert all(c["full_scans"] >= 1 and c["input_px"] > 0 for c in doc["regions"].values())
        assert sub.on("stereopose/demo/available")[-1] == "online"
    finally:
        rc = _stop(proc, log)
    assert rc == 0, log.read_text()
    logged = [e for e in query_events(db) if e["type"] in ZONE_TYPES]
    assert logged
    wait_until(lambda: len(sub.on("stereopose/demo/events")) >= len(logged), "MQTT events")
    wait_until(lambda: len(receiver.bodies) >= len(logged), "webhook events")
    on_mqtt = [json.loads(p) for p in sub.on("stereopose/demo/events")]
    assert sorted(map(_key, logged)) == sorted(_key(e) for e in on_mqtt if e["type"] in ZONE_TYPES)
    assert sorted(map(_key, logged)) == sorted(
        _key(e) for e in receiver.bodies if e["type"] in ZONE_TYPES
    )
    assert sub.on("stereopose/demo/available")[-1] == "offline"
    segments = sorted((data / "poses").glob("*.jsonl.gz"))
    lines = gzip.decompress(segments[-1].read_bytes()).decode().splitlines()
    assert lines and all("frame" in json.loads(line) for line in lines)
    assert "Traceback" not in log.read_text()
    # its first lines say which interfaces are on
    assert "interfaces: MQTT on 127.0.0.1:" in log.read_text()
    assert "IEC 104 off, OPC UA off" in log.read_text()


def _fresh(events: list[dict]) -> list[dict]:
    """A run's own person events: not the exits that closed the last run's zones."""
    return [e for e in events if e["person"] >= 0 and not e["restart"]]


def test_kill_9_then_restart_keeps_events_and_never_reuses_an_id(setup):
    config, data, _, _, _, log = setup
    db = data / "events.sqlite"
    proc = _start(config, log)
    try:
        wait_until(
            lambda: db.exists() and len(query_events(db)) >= 1,
            "events in the log",
            timeout_s=90,
            poll_s=0.5,
        )
    finally:
        proc.kill()
        proc.wait(timeout=10)
    before = query_events(db)
    first_ids = {e["person"] for e in before if e["person"] >= 0}
    proc = _start(config, log)
    try:
        wait_until(
            lambda: _fresh(query_events(db)[len(before) :]),
            "events of the new run",
            timeout_s=90,
            poll_s=0.5,
        )
    finally:
        rc = _stop(proc, log)
    assert rc == 0, log.read_text()
    after = query_events(db)
    assert after[: len(before)] == before  # every committed event kept
    new_run = _fresh(after[len(before) :])
    assert new_run and not {e["person"] for e in new_run} & first_ids
    # who was inside a zone when it was killed is let out, marked so, before anything else
    inside = {(e["zone"], e["person"]) for e in before if e["type"] == "enter"} - {
        (e["zone"], e["person"]) for e in before if e["type"] == "exit"
    }
    closed = {(e["zone"], e["person"]) for e in after[len(before) :] if e["restart"]}
    assert closed == inside
