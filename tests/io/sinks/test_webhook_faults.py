"""The webhook against a receiver that misbehaves at the socket level: no reply stops it, every
event ends in exactly one count, and the events after the faults are delivered."""

from __future__ import annotations

import json
import socket
import struct
import threading
import time

import pytest

from stereopose.io.sinks.webhook import WebhookSink
from stereopose.types import Event


def event(k: int) -> Event:
    return Event(
        t=k / 25, frame=k, person=1, zone="panel", kind="energized", type="enter", onset_t=k / 25
    )


def _request(conn: socket.socket) -> bytes:
    """One HTTP request read whole (headers, then Content-Length bytes of body)."""
    data = b""
    while b"\r\n\r\n" not in data:
        chunk = conn.recv(65536)
        if not chunk:
            return data
        data += chunk
    head, _, body = data.partition(b"\r\n\r\n")
    length = next(
        int(line.split(b":")[1])
        for line in head.split(b"\r\n")
        if line.lower().startswith(b"content-length")
    )
    while len(body) < length:
        chunk = conn.recv(65536)
        if not chunk:
            break
        body += chunk
    return body


def _ok(conn: socket.socket) -> None:
    conn.sendall(b"HTTP/1.1 200 OK\r\nContent-Length: 2\r\nConnection: close\r\n\r\nok")


def _until_cut(conn: socket.socket, send: bytes = b"", every_s: float = 0.0) -> None:
    """Send `send` byte by byte every `every_s` (or nothing) until the client cuts us off."""
    deadline = time.monotonic() + 30
    conn.settimeout(every_s or 0.05)
    while time.monotonic() < deadline:
        try:
            if send:
                conn.send(send[:1])
                send = send[1:] or b"x"
            if not conn.recv(1):
                return  # the client closed its side
        except TimeoutError:
            continue
        except OSError:
            return


REPLIES = {
    "bad status line": lambda c: c.sendall(b"HTTP/1.1 OK-ish maybe\r\n\r\n"),
    "garbage": lambda c: c.sendall(b"\x00\xff not http at all\r\n\r\n"),
    "short body": lambda c: c.sendall(b"HTTP/1.1 200 OK\r\nContent-Length: 1000\r\n\r\nabc"),
    "closed without reply": lambda c: None,
    "reset": lambda c: c.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0)),
    "no reply": lambda c: _until_cut(c),
    "slow drip": lambda c: _until_cut(c, b"HTTP/1.1 200 OK\r\n", every_s=0.05),
    "500": lambda c: c.sendall(b"HTTP/1.1 500 Oops\r\nContent-Length: 0\r\n\r\n"),
    "503 then hang up": lambda c: c.sendall(b"HTTP/1.1 503 Busy\r\n"),
    "404": lambda c: c.sendall(b"HTTP/1.1 404 Not Found\r\nContent-Length: 0\r\n\r\n"),
}


class Receiver:
    """A TCP server answering its n-th connection as `script[n]` says (a REPLIES key), and
    every connection after the script with a proper 200; the bodies of those are kept."""

    def __init__(self, script: list[str]) -> None:
        self.script = list(script)
        self.connections = 0
        self.received: list[dict] = []
        self.sock = socket.create_server(("127.0.0.1", 0))
        self.url = f"http://127.0.0.1:{self.sock.getsockname()[1]}/hook"
        self._threads: list[threading.Thread] = []
        threading.Thread(target=self._accept, daemon=True).start()

    def _accept(self) -> None:
        while True:
            try:
                conn, _ = self.sock.accept()
            except OSError:
                return
            n, self.connections = self.connections, self.connections + 1
            t = threading.Thread(target=self._serve, args=(conn, n), daemon=True)
            self._threads.append(t)
            t.start()

    def _serve(self, conn: socket.socket, n: int) -> None:
        with conn:
            body = _request(conn)
            if n < len(self.script):
                REPLIES[self.script[n]](conn)
            else:
                self.received.append(json.loads(body))
                _ok(conn)

    def stop(self) -> None:
        self.sock.close()
        for t in self._threads:
            t.join(5)


# with no retries, each event meets one fault: (fault, its count)
OUTCOMES = [
    ("bad status line", "failed"),
    ("garbage", "failed"),
    ("short body", "delivered"),  # the 200 came: the body is the receiver's business
    ("closed without reply", "failed"),
    ("reset", "failed"),
    ("no reply", "failed"),
    ("slow drip", "failed"),
    ("500", "failed"),
    ("503 then hang up", "failed"),
    ("404", "failed"),
]


@pytest.fixture
def receiver():
    made: list[Receiver] = []
    yield lambda script: made.append(Receiver(script)) or made[-1]
    for r in made:
        r.stop()


def test_no_reply_stops_the_sender_and_each_event_is_counted_once(receiver) -> None:
    server = receiver([fault for fault, _ in OUTCOMES])
    sink = WebhookSink(server.url, retries=0, timeout_s=0.5, drain_timeout_s=30)
    n = len(OUTCOMES) + 3
    sink.write_events([event(k) for k in range(n)])
    sink.close()
    want = [outcome for _, outcome in OUTCOMES].count("delivered") + 3
    assert (sink.delivered, sink.failed, sink.dropped) == (want, n - want, 0)
    assert sink._thread.is_alive() is False  # it ended because it was closed, not killed
    # the three events after the faults reached the receiver, in order
    assert [r["frame"] for r in server.received] == list(range(len(OUTCOMES), n))
    assert sink.incomplete is not None and f"{n - want} event(s) not delivered" in sink.incomplete


def test_retries_carry_an_event_over_every_fault(receiver) -> None:
    faults = [f for f, outcome in OUTCOMES if outcome == "failed" and f != "404"]
    server = receiver(faults)
    sink = WebhookSink(
        server.url,
        retries=len(faults),
        backoff_s=0.001,
        max_backoff_s=0.002,
        timeout_s=0.5,
        drain_timeout_s=30,
    )
    sink.write_events([event(0), event(1)])
    sink.close()
    assert (sink.delivered, sink.failed, sink.dropped) == (2, 0, 0)
    assert sink.retried == len(faults) and sink.incomplete is None
    assert [r["frame"] for r in server.received] == [0, 1]


def test_a_refusal_is_not_retried(receiver) -> None:
    server = receiver(["404"])
    sink = WebhookSink(server.url, retries=3, backoff_s=0.001, timeout_s=0.5)
    sink.write_events([event(0), event(1)])
    sink.close()
    assert (sink.delivered, sink.failed, sink.retried) == (1, 1, 0)
    assert [r["frame"] for r in server.received] == [1]


def test_closing_while_the_receiver_hangs_counts_the_event_on_the_wire(receiver) -> None:
    server = receiver(["no reply"] * 5)
    sink = WebhookSink(server.url, retries=0, timeout_s=2.0, drain_timeout_s=0.0)
    sink.write_events([event(k) for k in range(4)])
    # closing at once: the event on the wire ends by its timeout, the rest were never sent
    sink.close()
    assert sink.delivered + sink.failed + sink.dropped == 4
    assert sink.delivered == 0 and sink.dropped >= 3
