"""Health tells the truth about alarms: each alarm output as `stereopose serve` wires it
(Guarded, registered by serve_parts.output_health), failing for real, seen over a real
server in /api/health and /metrics, and back to ok once it recovers. A mosquitto broker
stopped, a webhook receiver answering 500, the event log locked by another connection or
on a full file system."""

from __future__ import annotations

import contextlib
import os
import shutil
import sqlite3
import subprocess
import threading
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

import pytest
from prometheus_client.parser import text_string_to_metric_families

from brokers import Broker
from served import event, get, get_json, serving
from stereopose.io.sinks.base import Guarded
from stereopose.io.sinks.eventwriter import LockWaits, SqliteSink
from stereopose.io.sinks.mqtt import MqttSettings, MqttSink
from stereopose.io.sinks.webhook import WebhookSink
from stereopose.site.health.state import ServiceState
from stereopose.site.parts import output_health
from waiting import wait_until


def _state() -> ServiceState:
    state = ServiceState(["cam"], camera_timeout_s=86400.0)
    state.camera_frame("cam")
    return state


def _watch(state: ServiceState, name: str, sink, failures: dict) -> Guarded:
    guarded = Guarded(sink, name, failures)
    state.register_output(name, output_health(sink, guarded))
    return guarded


def _health(url: str) -> dict:
    status, h = get_json(url + "/api/health")
    assert status == 200, h
    return h


def _outputs_metrics(url: str) -> dict[tuple[str, str], float]:
    _, _, body = get(url + "/metrics")
    found = {}
    for family in text_string_to_metric_families(body.decode()):
        if family.name.startswith("stereopose_output_"):
            for s in family.samples:
                found[(s.name, s.labels["output"])] = s.value
    return found


def _degraded_by(url: str, output: str) -> bool:
    h = _health(url)
    return h["status"] == "degraded" and any(
        p.startswith(f"output {output} failing") for p in h["problems"]
    )


def test_an_mqtt_broker_outage_is_degraded_with_the_alarms_waiting(tmp_path: Path) -> None:
    broker = Broker(tmp_path / "broker").start()
    state, failures = _state(), {}
    settings = MqttSettings(
        host="127.0.0.1",
        port=broker.port,
        site="s",
        reconnect_min_s=0.05,
        reconnect_max_s=0.2,
        close_timeout_s=2.0,
    )
    mqtt = _watch(state, "mqtt", MqttSink(settings), failures)
    try:
        with serving(state) as server:
            url = server.url
            wait_until(lambda: _health(url)["status"] == "ok", "health ok while connected")
            assert _outputs_metrics(url)[("stereopose_output_up", "mqtt")] == 1.0
            broker.stop()
            wait_until(lambda: _degraded_by(url, "mqtt"), "health degraded by the outage")
            for k in range(17):
                mqtt.write_events([event("enter", k)])
            h = _health(url)
            assert h["outputs"]["mqtt"]["state"] == "down"
            assert h["outputs"]["mqtt"]["waiting"] >= 17
            (problem,) = [p for p in h["problems"] if p.startswith("output mqtt")]
            assert "broker" in problem and "waiting)" in problem, problem
            assert str(broker.port) not in problem  # no address for anonymous clients
            m = _outputs_metrics(url)
            assert m[("stereopose_output_up", "mqtt")] == 0.0
            assert m[("stereopose_output_waiting", "mqtt")] >= 17
            broker.start()
            wait_until(
                lambda: mqtt.figures()["events"]["published"] == 17,
                "the broker's acknowledgements of the alarms",
            )
            wait_until(lambda: _health(url)["status"] == "ok", "health ok once delivered")
            up = {"state": "up", "waiting": 0, "reason": None, "backlog_s": 0.0}
            assert _health(url)["outputs"]["mqtt"] == up
            assert _outputs_metrics(url)[("stereopose_output_up", "mqtt")] == 1.0
    finally:
        mqtt.close()
        broker.stop()
    assert failures == {}


class _FlakyReceiver:
    """A webhook receiver on 127.0.0.1 answering 500 while `failing` is set, else 200."""

    def __init__(self) -> None:
        self.failing = threading.Event()
        self.received = 0
        outer = self

        class Handler(BaseHTTPRequestHandler):
            def do_POST(self) -> None:
                self.rfile.read(int(self.headers.get("Content-Length", 0)))
                if outer.failing.is_set():
                    self.send_response(500)
                else:
                    outer.received += 1
                    self.send_response(200)
                self.send_header("Content-Length", "0")
                self.end_headers()

            def log_message(self, *args) -> None:
                pass

        self.server = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.url = f"http://user:pw@127.0.0.1:{self.server.server_port}/hook?key=secret"
        threading.Thread(target=self.server.serve_forever, daemon=True).start()

    def close(self) -> None:
        self.server.shutdown()
        self.server.server_close()


def test_a_failing_webhook_is_degraded_until_it_delivers_again() -> None:
    receiver = _FlakyReceiver()
    state, failures = _state(), {}
    hook = _watch(
        state,
        "webhook",
        WebhookSink(receiver.url, retries=1000, backoff_s=0.05, max_backoff_s=0.1),
        failures,
    )
    try:
        with serving(state) as server:
            url = server.url
            hook.write_events([event("enter", 1)])
            wait_until(lambda: receiver.received == 1, "the first event delivered")
            wait_until(lambda: _health(url)["status"] == "ok", "health ok")
            receiver.failing.set()
            hook.write_events([event("enter", k) for k in range(2, 6)])
            wait_until(lambda: _degraded_by(url, "webhook"), "health degraded by the receiver")
            h = _health(url)
            assert h["outputs"]["webhook"]["waiting"] == 4
            assert "HTTP 500" in h["outputs"]["webhook"]["reason"]
            assert "secret" not in str(h) and "127.0.0.1" not in str(h)  # no URL shown
            m = _outputs_metrics(url)
            assert m[("stereopose_output_up", "webhook")] == 0.0
            assert m[("stereopose_output_waiting", "webhook")] == 4.0
            receiver.failing.clear()
            wait_until(lambda: receiver.received == 5, "the waiting events delivered")
            wait_until(lambda: _health(url)["status"] == "ok", "health ok again")
            assert _outputs_metrics(url)[("stereopose_output_up", "webhook")] == 1.0
    finally:
        hook.close()
        receiver.close()


def test_an_event_log_locked_by_another_connection_is_degraded_then_ok(tmp_path: Path) -> None:
    path = tmp_path / "events.sqlite"
    state, failures = _state(), {}
    db = _watch(
        state, "events_db", SqliteSink(path, waits=LockWaits(busy_s=0.01, retry_s=0.01)), failures
    )
    other = sqlite3.connect(path, isolation_level=None)
    try:
        with serving(state) as server:
            url = server.url
            db.write_events([event("enter", 1)])
            assert _health(url)["status"] == "ok"
            other.execute("BEGIN IMMEDIATE")  # another process holds the write lock
            db.write_events([event("enter", 2)])
            h = _health(url)
            assert h["status"] == "degraded"
            assert h["outputs"]["events_db"]["state"] == "down"
            assert h["outputs"]["events_db"]["waiting"] == 1
            assert "locked" in h["outputs"]["events_db"]["reason"]
            assert str(tmp_path) not in str(h)
            assert _outputs_metrics(url)[("stereopose_output_up", "events_db")] == 0.0
            other.execute("COMMIT")
            wait_until(
                lambda: db.write_events([]) or _health(url)["status"] == "ok",
                "health ok once the events are stored",
            )
            assert _outputs_metrics(url)[("stereopose_output_waiting", "events_db")] == 0.0
    finally:
        other.close()
        db.close()


@contextlib.contextmanager
def _small_tmpfs(path: Path, size: str):
    path.mkdir()
    if shutil.which("mount") is None or os.geteuid() != 0:
        pytest.skip("needs root and mount(8) to make a small file system to fill")
    done = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(path)],
        capture_output=True,
        text=True,
    )
    if done.returncode != 0:
        pytest.skip(f"mounting a tmpfs is not permitted here: {done.stderr.strip()}")
    try:
        yield path
    finally:
        subprocess.run(["umount", str(path)], check=True)


def test_an_event_log_on_a_full_disk_is_degraded_until_there_is_room(tmp_path: Path) -> None:
    with _small_tmpfs(tmp_path / "disk", "1m") as disk:
        state, failures = _state(), {}
        db = _watch(
            state,
            "events_db",
            SqliteSink(disk / "events.sqlite", waits=LockWaits(retry_s=0.01)),
            failures,
        )
        filler = disk / "filler"
        try:
            with serving(state) as server:
                url = server.url
                db.write_events([event("enter", 1)])
                assert _health(url)["status"] == "ok"
                # unbuffered: a short last write must not leave bytes for close() to fail on
                with open(filler, "wb", buffering=0) as f, contextlib.suppress(OSError):
                    while True:
                        f.write(b"\0" * 65536)  # until the disk is full
                for k in range(2, 200):  # a frame's events at a time, as the loop writes
                    db.write_events([event("enter", k)])
                    if not db.health()[0]:
                        break
                h = _health(url)
                assert h["status"] == "degraded", h
                out = h["outputs"]["events_db"]
                assert out["state"] == "down" and out["waiting"] >= 1
                assert "full" in out["reason"] or "disk" in out["reason"], out
                assert str(disk) not in str(h)
                filler.unlink()
                wait_until(
                    lambda: db.write_events([]) or _health(url)["status"] == "ok",
                    "health ok once there is room",
                )
        finally:
            db.close()
