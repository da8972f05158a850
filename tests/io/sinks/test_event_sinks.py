"""Event sinks: JSON lines, SQLite (append, crash safety), webhook (retries, down, full)."""

from __future__ import annotations

import dataclasses
import json
import os
import signal
import sqlite3
import subprocess
import sys
import threading
import time
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

import pytest

from stereopose.errors import StereoposeError
from stereopose.fence.sinks import (
    JsonlSink,
    SqliteSink,
    WebhookSink,
    describe,
    query_events,
    read_events,
)
from stereopose.types import Event


def event(k: int, **kw) -> Event:
    base = dict(
        t=k / 25,
        frame=k,
        person=1 + k % 3,
        zone=("panel", "bench")[k % 2],
        kind=("energized", "work_area")[k % 2],
        type=("enter", "exit")[k // 2 % 2],
        onset_t=(k - 2) / 25,
        joint="right_wrist",
        position=(1.0, 2.0),
    )
    base.update(kw)
    return Event(**base)


def test_jsonl_follows_the_contract(tmp_path: Path) -> None:
    sink = JsonlSink(tmp_path / "e.jsonl")
    sink.write([event(0), event(1, type="approach", distance_m=0.31234)])
    sink.write([])
    sink.close()
    lines = [json.loads(x) for x in (tmp_path / "e.jsonl").read_text().splitlines()]
    assert len(lines) == 2
    for rec in lines:
        assert {"t", "frame", "person", "zone", "type", "kind", "position"} <= set(rec)
    assert lines[1]["distance_m"] == 0.3123 and lines[1]["type"] == "approach"
    assert "allowed" not in lines[0] and "lost" not in lines[0]
    assert "right_wrist" in describe(event(0))
    back = read_events(tmp_path / "e.jsonl")
    assert back[0] == dataclasses.replace(event(0), t=round(event(0).t, 6))
    assert back[1].distance_m == 0.3123
    (tmp_path / "bad.jsonl").write_text('{"t": 1}\n')
    with pytest.raises(StereoposeError, match=r"bad\.jsonl:1: malformed event line"):
        read_events(tmp_path / "bad.jsonl")


def test_sqlite_appends_runs_and_filters(tmp_path: Path) -> None:
    db = tmp_path / "e.sqlite"
    for _ in range(2):
        sink = SqliteSink(db, site="site.toml", source="pose/")
        sink.write([event(k) for k in range(6)])
        sink.close()
    rows = query_events(db)
    assert len(rows) == 12 and {r["run"] for r in rows} == {1, 2}
    assert len(query_events(db, person=1)) == 4
    assert len(query_events(db, zone="panel", event_type="enter")) == 4
    assert all(r["t"] >= 0.1 for r in query_events(db, since=0.1))
    con = sqlite3.connect(db)
    assert con.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
    con.close()


def test_sqlite_errors_name_the_file(tmp_path: Path) -> None:
    with pytest.raises(StereoposeError, match="event database not found"):
        query_events(tmp_path / "none.sqlite")
    bad = tmp_path / "bad.sqlite"
    bad.write_text("not a database, clearly" * 100)
    with pytest.raises(StereoposeError, match=r"bad\.sqlite"):
        query_events(bad)
    with pytest.raises(StereoposeError, match=r"bad\.sqlite"):
        SqliteSink(bad)


WRITER = """
import sys, time
from stereopose.fence.sinks import SqliteSink
from stereopose.types import Event
sink = SqliteSink(sys.argv[1])
k = 0
while True:
    sink.write([Event(t=k / 25, frame=k, person=1, zone="z", kind="energized", type="enter",
                      onset_t=k / 25) for _ in range(3)])
    k += 1
    print(3 * k, flush=True)
    time.sleep(0.002)
"""


@pytest.mark.slow
def test_sqlite_survives_sigkill(tmp_path: Path) -> None:
    db = tmp_path / "e.sqlite"
    proc = subprocess.Popen(
        [sys.executable, "-c", WRITER, str(db)], stdout=subprocess.PIPE, text=True
    )
    committed = 0
    try:
        for line in proc.stdout:
            committed = int(line)
            if committed >= 300:
                break
    finally:
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
    assert proc.returncode == -signal.SIGKILL
    con = sqlite3.connect(db)
    assert con.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
    n = con.execute("SELECT count(*) FROM events").fetchone()[0]
    con.close()
    assert n >= committed and n % 3 == 0  # every reported commit, never half a frame
    # the log goes on after the crash
    sink = SqliteSink(db)
    sink.write([event(0)])
    sink.close()
    assert len(query_events(db)) == n + 1


class Server:
    """A local HTTP server; `fail` first requests answer 500; `delay` slows each request."""

    def __init__(self, fail: int = 0, delay: float = 0.0) -> None:
        self.received: list[dict] = []
        self.requests = 0
        outer = self

        class Handler(BaseHTTPRequestHandler):
            def do_POST(self) -> None:
                body = self.rfile.read(int(self.headers["Content-Length"]))
                outer.requests += 1
                time.sleep(delay)
                if outer.requests <= fail:
                    self.send_response(500)
                    self.end_headers()
                    return
                outer.received.append(json.loads(body))
                self.send_response(200)
                self.end_headers()

            def log_message(self, *args) -> None:
                pass

        self.httpd = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.url = f"http://127.0.0.1:{self.httpd.server_address[1]}/events"
        threading.Thread(target=self.httpd.serve_forever, daemon=True).start()

    def stop(self) -> None:
        self.httpd.shutdown()
        self.httpd.server_close()


def test_webhook_delivers_and_retries() -> None:
    server = Server(fail=2)
    try:
        sink = WebhookSink(server.url, backoff_s=0.01)
        sink.write([event(k) for k in range(5)])
        sink.close()
    finally:
        server.stop()
    assert sink.sent == 5 and sink.retried == 2 and sink.failed == 0 and sink.dropped == 0
    assert [r["frame"] for r in server.received] == list(range(5))


def test_webhook_server_down_is_counted_not_fatal() -> None:
    server = Server()
    url = server.url
    server.stop()  # nothing listens there any more
    sink = WebhookSink(url, retries=2, backoff_s=0.01, drain_timeout_s=5.0)
    t0 = time.perf_counter()
    sink.write([event(k) for k in range(3)])
    assert time.perf_counter() - t0 < 0.05  # never blocks the frame loop
    sink.close()
    assert sink.sent == 0 and sink.failed + sink.dropped == 3


def test_webhook_full_queue_drops_and_counts() -> None:
    server = Server(delay=0.2)
    try:
        sink = WebhookSink(server.url, queue_size=3, drain_timeout_s=0.1)
        t0 = time.perf_counter()
        sink.write([event(k) for k in range(50)])
        assert time.perf_counter() - t0 < 0.05
        sink.close()
    finally:
        server.stop()
    assert sink.dropped >= 45 and sink.sent + sink.dropped + sink.failed == 50


def test_webhook_url_is_checked() -> None:
    with pytest.raises(StereoposeError, match="http:// or https://"):
        WebhookSink("ftp://example")
