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
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

import pytest

from stereopose.errors import StereoposeError
from stereopose.io.records import event_from_record
from stereopose.io.sinks import FrameResult
from stereopose.io.sinks.events import (
    CallbackSink,
    JsonlSink,
    WebhookSink,
    describe,
    query_events,
    read_events,
)
from stereopose.io.sinks.eventwriter import SqliteSink
from stereopose.types import Event, People3D
from waiting import wait_until


def returns(call, *args, timeout_s: float = 20.0) -> None:
    """``call(*args)`` returns (run on a thread, waited for with a deadline): it does not
    block on whatever the test holds up."""
    t = threading.Thread(target=call, args=args, daemon=True)
    t.start()
    t.join(timeout_s)
    assert not t.is_alive(), f"{call.__qualname__} blocked for {timeout_s} s"


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
    sink.write_events([event(0), event(1, type="approach", distance_m=0.31234)])
    sink.write_events([])
    assert sink.close() == [tmp_path / "e.jsonl"] and sink.close() == []
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
        sink.write_events([event(k) for k in range(6)])
        sink.close()
    rows = query_events(db)
    assert len(rows) == 12 and {r["run"] for r in rows} == {1, 2}
    assert [event_from_record(r) for r in rows[:6]] == [event(k) for k in range(6)]
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
from stereopose.io.sinks.eventwriter import SqliteSink
from stereopose.types import Event
sink = SqliteSink(sys.argv[1])
k = 0
while True:
    sink.write_events([Event(t=k / 25, frame=k, person=1, zone="z", kind="energized", type="enter",
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
    sink.write_events([event(0)])
    sink.close()
    assert len(query_events(db)) == n + 1


class Server:
    """A local HTTP server; the `fail` first requests answer 500; with a `gate`, each request
    waits for it to be set before answering."""

    def __init__(self, fail: int = 0, gate: threading.Event | None = None) -> None:
        self.received: list[dict] = []
        self.requests = 0
        outer = self

        class Handler(BaseHTTPRequestHandler):
            def do_POST(self) -> None:
                body = self.rfile.read(int(self.headers["Content-Length"]))
                outer.requests += 1
                if gate is not None:
                    gate.wait(30)
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
        sink.write_events([event(k) for k in range(5)])
        sink.close()
    finally:
        server.stop()
    assert sink.sent == 5 and sink.retried == 2 and sink.failed == 0 and sink.dropped == 0
    assert [r["frame"] for r in server.received] == list(range(5))


def test_webhook_server_down_is_counted_not_fatal() -> None:
    server = Server()
    url = server.url
    server.stop()  # nothing listens there any more
    held = threading.Event()  # the retries wait on this: the sender is stuck until it is set
    sink = WebhookSink(url, retries=2, sleep=lambda s: held.wait(30), drain_timeout_s=5.0)
    sink.write_events([event(0)])
    wait_until(lambda: sink.retried >= 1, "the first POST to fail and its retry to wait")
    returns(sink.write_events, [event(k) for k in range(1, 3)])  # never blocks the frame loop
    held.set()
    sink.close()
    assert sink.sent == 0 and sink.failed + sink.dropped == 3


def test_webhook_full_queue_drops_and_counts() -> None:
    gate = threading.Event()  # the server holds every request until it is set
    server = Server(gate=gate)
    try:
        sink = WebhookSink(server.url, queue_size=3)
        sink.write_events([event(0)])
        wait_until(lambda: server.requests == 1, "the first event's POST to reach the server")
        # the sender waits on the server: 3 events fill the queue, the other 46 are dropped
        returns(sink.write_events, [event(k) for k in range(1, 50)])
        assert sink.dropped == 46 and sink.queue.qsize() == 3
        gate.set()
        sink.close()
    finally:
        gate.set()
        server.stop()
    assert sink.sent == 4 and sink.dropped == 46 and sink.failed == 0
    assert [r["frame"] for r in server.received] == [0, 1, 2, 3]


def test_event_sinks_take_a_frame_and_close_once(tmp_path: Path) -> None:
    got: list[list[Event]] = []
    sinks = [
        JsonlSink(tmp_path / "e.jsonl"),
        SqliteSink(tmp_path / "e.sqlite"),
        CallbackSink(got.append),
    ]
    nobody = People3D.empty(0, 2)
    for k in range(4):
        evs = [event(k)] if k % 2 else []
        for sink in sinks:
            sink.write(FrameResult(k, k / 25, {}, nobody, evs))
    paths = [p for sink in sinks for p in sink.close()]
    assert paths == [tmp_path / "e.jsonl", tmp_path / "e.sqlite"]
    assert [s.close() for s in sinks] == [[], [], []]
    assert got == [[event(1)], [event(3)]]
    assert [e.frame for e in read_events(tmp_path / "e.jsonl")] == [1, 3]
    assert [r["frame"] for r in query_events(tmp_path / "e.sqlite")] == [1, 3]


def test_webhook_url_is_checked() -> None:
    with pytest.raises(StereoposeError, match="http:// or https://"):
        WebhookSink("ftp://example")
