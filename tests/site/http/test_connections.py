"""Connections that cannot be held, against a real server on real loopback sockets: idle and
slow (slowloris) connections closed while health is served, request heads over 16 KiB refused
before any route runs, a cap per client address, answers in progress bounded with places for
health, and streams and keep-alive clients untouched by the timeouts.

Client addresses other than 127.0.0.1 are other loopback addresses (127.0.0.2, ...), which
Linux lets a socket bind to."""

from __future__ import annotations

import asyncio
import http.client
import json
import socket
import threading
from collections.abc import AsyncIterator, Iterator

import pytest
from fastapi import FastAPI
from fastapi.responses import StreamingResponse

from served import Clock, frame_result, get, get_json, serving
from stereopose.errors import ConfigError
from stereopose.site.health.state import ServiceState
from stereopose.site.http.app import create_app
from stereopose.web.connections import MAX_HEADER_BYTES, ConnectionLimits, client_key
from stereopose.web.server import Server, ServeSettings
from waiting import wait_until


class Peer:
    """One raw client connection from a loopback `source` address: what it received, and
    whether the server closed it (read without blocking)."""

    def __init__(self, port: int, source: str = "127.0.0.1") -> None:
        self.sock = socket.socket()
        self.sock.bind((source, 0))
        self.sock.settimeout(10)
        self.sock.connect(("127.0.0.1", port))
        self.sock.setblocking(False)
        self.received = b""
        self.gone = False
        self.port = port

    def closed(self) -> bool:
        """Whether the server closed (or reset) the connection; what came is kept."""
        while not self.gone:
            try:
                chunk = self.sock.recv(65536)
            except BlockingIOError:
                return False
            except OSError:  # reset: closed too
                chunk = b""
            if not chunk:
                self.gone = True
            self.received += chunk
        return True

    def send(self, data: bytes) -> bool:
        """Send `data`; False when the server has closed the connection."""
        if self.closed():
            return False
        try:
            self.sock.sendall(data)
        except (BlockingIOError, OSError):
            self.gone = True
            return False
        return True

    def request(self, path: str) -> bytes:
        return b"GET %s HTTP/1.1\r\nhost: 127.0.0.1:%d\r\n\r\n" % (path.encode(), self.port)

    def close(self) -> None:
        self.sock.close()


@pytest.fixture
def peers() -> Iterator[list[Peer]]:
    opened: list[Peer] = []
    yield opened
    for p in opened:
        p.close()


def healthy_state() -> ServiceState:
    """A state whose /api/health is 200: its camera up (the clock stands still), a frame."""
    clock = Clock()
    state = ServiceState(["cam_01"], clock=clock)
    state.camera_frame("cam_01", clock.now)
    state.on_frame(frame_result(1, 1), {"detect": 0.01})
    return state


def health_served(url: str) -> bool:
    """Whether /api/health answers 200 "ok" and /metrics 200 (not a 503 of the door)."""
    status, _, body = get(url + "/api/health")
    if status != 200 or json.loads(body)["status"] != "ok":
        return False
    return get(url + "/metrics")[0] == 200


def sources(n: int, per_address: int) -> list[str]:
    """n client addresses, per_address connections each: 127.0.0.2, 127.0.0.2, ..."""
    return [f"127.0.0.{2 + i // per_address}" for i in range(n)]


def test_limits_are_checked():
    with pytest.raises(ConfigError, match=r"idle_s must be a number > 0, got 0"):
        ConnectionLimits(idle_s=0)
    with pytest.raises(ConfigError, match=r"max_per_address must be an integer >= 1, got 0"):
        ConnectionLimits(max_per_address=0)
    with pytest.raises(ConfigError, match=r"max_connections must be above .* 72 <= 64 \+ 8"):
        ConnectionLimits(max_connections=72)


@pytest.mark.parametrize(
    ("host", "key"),
    [
        ("127.0.0.2", "127.0.0.2"),
        ("::1", "::1"),
        ("::ffff:10.0.0.7", "10.0.0.7"),
        ("2001:db8:1:2:aaaa::1", "2001:db8:1:2::/64"),
        ("2001:db8:1:2:bbbb::9", "2001:db8:1:2::/64"),
        ("", ""),
    ],
)
def test_a_client_address_is_an_ipv4_address_or_an_ipv6_64(host: str, key: str):
    assert client_key(host) == key


def test_idle_connections_do_not_hold_health(peers):
    with serving(healthy_state(), limits=ConnectionLimits(idle_s=60, request_s=60)) as server:
        assert server.port is not None
        peers += [Peer(server.port, a) for a in sources(80, 16)]  # 5 addresses, 16 each
        assert health_served(server.url)
        assert not any(p.closed() for p in peers)  # room for all of them: none had to go


def test_silent_connections_are_closed(peers):
    with serving(healthy_state(), limits=ConnectionLimits(idle_s=1.0)) as server:
        assert server.port is not None
        peers += [Peer(server.port, a) for a in sources(64, 16)]
        wait_until(lambda: all(p.closed() for p in peers), "the silent connections to close")
        assert all(p.received == b"" for p in peers)  # closed, not answered
        assert health_served(server.url)


def test_slowloris_is_disconnected_and_does_not_block_health(peers):
    limits = ConnectionLimits(request_s=1.0, idle_s=60)  # the idle timer is not what acts
    with serving(healthy_state(), limits=limits) as server:
        assert server.port is not None
        peers += [Peer(server.port, a) for a in sources(64, 16)]
        for p in peers:
            assert p.send(b"GET /api/health HTTP/1.1\r\n")
        served = False
        for i in range(400):  # a header line to each, every 0.05 s, until all are closed
            still = [p for p in peers if p.send(b"x-slow-%d: a\r\n" % i)]
            if not still:
                break
            if not served:
                served = health_served(server.url)  # while they all still send
            threading.Event().wait(0.05)  # the attacker's pace
        assert served
        assert all(p.closed() for p in peers), "slow senders still connected"
        answered = [p.received for p in peers if p.received]
        assert answered and all(a.startswith(b"HTTP/1.1 408 ") for a in answered)
        assert health_served(server.url)


def head_of(port: int, size: int, newline: bytes = b"\r\n") -> bytes:
    """A GET /api/seen whose line and headers are `size` bytes in all."""
    start = b"GET /api/seen HTTP/1.1" + newline + b"host: 127.0.0.1:%d" % port + newline
    pad = size - len(start) - len(b"x-pad: ") - 2 * len(newline)
    return start + b"x-pad: " + b"a" * pad + newline + newline


def answer_of(port: int, data: bytes) -> bytes:
    """What the server answers to `data`, until it closes the connection."""
    p = Peer(port)
    try:
        assert p.send(data)
        wait_until(p.closed, "the server to close the connection")
        return p.received
    finally:
        p.close()


def test_request_heads_over_16_kib_are_refused_before_any_route():
    app = create_app(ServiceState())
    seen: list[int] = []

    @app.get("/api/seen")
    async def seen_route() -> dict:
        seen.append(1)
        return {}

    with Server(app, ServeSettings(port=0)) as server:
        port = server.port
        assert port is not None
        for newline in (b"\r\n", b"\n"):  # h11 takes a bare newline too
            answer = answer_of(port, head_of(port, 60_000, newline))
            assert answer.startswith(b"HTTP/1.1 431 "), answer[:80]
            assert b"over 16384 bytes" in answer
        close = b"GET /api/seen HTTP/1.1\r\nhost: x\r\nconnection: close\r\n\r\n"
        pipelined = answer_of(port, head_of(port, 200) + head_of(port, 30_000) + close)
        assert pipelined.startswith(b"HTTP/1.1 200 ") and b"HTTP/1.1 431 " in pipelined
        assert len(seen) == 1  # only the small one reached the route
        status, _, _ = get(server.url + "/api/seen", headers={"x-pad": "a" * 15_000})
        assert status == 200 and len(seen) == 2  # just under the limit: served
        assert MAX_HEADER_BYTES == 16 * 1024


def test_a_request_framed_both_ways_is_refused_and_its_connection_closed():
    app = create_app(ServiceState())
    seen: list[str] = []

    @app.post("/api/seen")
    async def seen_post() -> dict:
        seen.append("post")
        return {}

    @app.get("/api/seen")
    async def seen_get() -> dict:
        seen.append("get")
        return {}

    with Server(app, ServeSettings(port=0)) as server:
        port = server.port
        assert port is not None
        hidden = b"GET /api/seen HTTP/1.1\r\nhost: x\r\n\r\n"
        body = b"0\r\n\r\n" + hidden  # chunked: empty; by length: a second request follows
        smuggled = (
            b"POST /api/seen HTTP/1.1\r\nhost: x\r\ncontent-type: application/json\r\n"
            b"content-length: %d\r\ntransfer-encoding: chunked\r\n\r\n" % len(body) + body
        )
        answer = answer_of(port, smuggled)
        assert answer.startswith(b"HTTP/1.1 400 "), answer[:80]
        assert answer.count(b"HTTP/1.1") == 1  # the hidden request is never answered
        assert seen == []
        # each framing alone is served
        plain = (
            b"POST /api/seen HTTP/1.1\r\nhost: x\r\ncontent-length: 2\r\n"
            b"connection: close\r\n\r\n{}"
        )
        assert answer_of(port, plain).startswith(b"HTTP/1.1 200 ")
        assert seen == ["post"]


def holding_app(release: threading.Event) -> FastAPI:
    """The service's app with /api/hold: an answer streamed until `release` is set."""
    app = create_app(healthy_state())

    @app.get("/api/hold")
    async def hold() -> StreamingResponse:
        async def body() -> AsyncIterator[bytes]:
            yield b"holding\n"
            while not release.is_set():
                await asyncio.sleep(0.02)
            yield b"released\n"

        return StreamingResponse(body(), media_type="text/plain")

    return app


def got(p: Peer, marker: bytes) -> bool:
    """Whether `marker` has come on `p` (or `p` was closed without it: False for good)."""
    p.closed()
    return marker in p.received


def holding(port: int, source: str) -> Peer:
    """A connection from `source` whose answer is being streamed."""
    p = Peer(port, source)
    assert p.send(p.request("/api/hold"))
    wait_until(lambda: got(p, b"holding") or p.gone, "the answer to start")
    assert b"holding" in p.received
    return p


@pytest.fixture
def release() -> Iterator[threading.Event]:
    event = threading.Event()
    yield event
    event.set()


def test_one_address_holds_at_most_its_cap(peers, release):
    limits = ConnectionLimits(max_per_address=4, idle_s=60, request_s=60)
    with Server(holding_app(release), ServeSettings(port=0), limits=limits) as server:
        port = server.port
        assert port is not None
        peers += [Peer(port, "127.0.0.2") for _ in range(4)]
        newest = Peer(port, "127.0.0.2")  # its own longest waiting makes room
        peers.append(newest)
        wait_until(peers[0].closed, "the address's oldest idle connection to close")
        assert not any(p.closed() for p in peers[1:])
        assert newest.send(newest.request("/metrics"))
        wait_until(lambda: got(newest, b"\r\n\r\n"), "the newest one's answer")
        assert newest.received.startswith(b"HTTP/1.1 200 ")

        for p in peers[1:]:
            p.close()
        busy = [holding(port, "127.0.0.3") for _ in range(4)]
        peers += busy
        refused = Peer(port, "127.0.0.3")  # all four answering: no place for a fifth
        peers.append(refused)
        wait_until(refused.closed, "the fifth connection to be refused")
        assert refused.received.startswith(b"HTTP/1.1 503 ")
        assert b"retry-after: 1\r\n" in refused.received  # when to come back
        assert not any(p.closed() for p in busy)  # the streams go on
        assert health_served(server.url)  # another address is served
        release.set()
        wait_until(lambda: all(got(p, b"released") for p in busy), "the streams to end")


def test_answers_in_progress_are_bounded_and_health_keeps_its_places(peers, release):
    limits = ConnectionLimits(max_requests=4, health_reserve=2, max_connections=16)
    with Server(holding_app(release), ServeSettings(port=0), limits=limits) as server:
        port = server.port
        assert port is not None
        peers += [holding(port, "127.0.0.2") for _ in range(4)]
        status, headers, body = get(server.url + "/openapi.json")
        assert status == 503 and b"try again" in body  # a fifth answer: no place
        assert headers.get("retry-after") == "1"
        assert health_served(server.url)  # its places kept
        release.set()
        wait_until(lambda: all(got(p, b"released") for p in peers), "the streams to end")
        wait_until(lambda: get(server.url + "/openapi.json")[0] == 200, "room again")


def test_a_full_table_gives_way_to_health(peers):
    limits = ConnectionLimits(
        max_connections=12, max_requests=4, health_reserve=2, idle_s=60, request_s=60
    )
    with serving(healthy_state(), limits=limits) as server:
        assert server.port is not None
        peers += [Peer(server.port, a) for a in sources(12, 4)]
        wait_until(lambda: opened(server) == 12, "the table to be full")
        assert get_json(server.url + "/api/health")[0] == 200  # the longest waiting gave way
        wait_until(peers[0].closed, "the longest waiting connection to close")
        assert not any(p.closed() for p in peers[1:])


def opened(server: Server) -> int:
    """How many connections `server` holds (uvicorn's own count)."""
    assert server._server is not None
    return len(server._server.server_state.connections)


def test_streams_and_keep_alive_clients_outlive_the_timeouts(release):
    limits = ConnectionLimits(idle_s=1.0, request_s=1.0)
    app = holding_app(release)

    @app.get("/api/ticks")
    async def ticks() -> StreamingResponse:  # an SSE stream, a message every 0.1 s
        async def body() -> AsyncIterator[bytes]:
            for i in range(30):
                yield b"event: tick\ndata: %d\n\n" % i
                await asyncio.sleep(0.1)

        return StreamingResponse(body(), media_type="text/event-stream")

    @app.post("/api/echo")
    async def echo(body: dict) -> dict:
        return body

    with Server(app, ServeSettings(port=0), limits=limits) as server:
        assert server.port is not None
        stream = http.client.HTTPConnection("127.0.0.1", server.port, timeout=10)
        stream.request("GET", "/api/ticks")
        answer = stream.getresponse()
        assert answer.status == 200 and answer.headers["content-type"].startswith(
            "text/event-stream"
        )
        data = [line for line in answer.read().split(b"\n") if line.startswith(b"data: ")]
        assert data == [b"data: %d" % i for i in range(30)]  # 3 s of messages, all of them
        stream.close()

        client = http.client.HTTPConnection("127.0.0.1", server.port, timeout=10)
        client.connect()
        sock = client.sock
        for i in range(30):  # one connection, kept alive, request after request
            client.request(
                "POST", "/api/echo", json.dumps({"i": i}), {"content-type": "application/json"}
            )
            r = client.getresponse()
            assert (r.status, json.loads(r.read())) == (200, {"i": i})
        assert client.sock is sock
        client.close()


def _ask(port: int, source: str, path: str) -> int | str:
    """One request with http.client from `source`: its status, or the error's name."""
    c = http.client.HTTPConnection("127.0.0.1", port, timeout=20, source_address=(source, 0))
    try:
        c.request("GET", path)
        return c.getresponse().status
    except OSError as e:
        return type(e).__name__
    finally:
        c.close()


def _burst(port: int, source: str, n: int, path: str) -> list[str]:
    answers: list[int | str] = []
    threads = [
        threading.Thread(target=lambda: answers.append(_ask(port, source, path))) for _ in range(n)
    ]
    for t in threads:
        t.start()
    for t in threads:
        t.join(30)
    return sorted(map(str, answers))


def test_connections_past_the_cap_get_an_answer_never_a_reset(peers, release):
    """Forty requests at once from one address over its cap: each gets an HTTP answer (200,
    or 503 with Retry-After), never a TCP reset; with every place busy too."""
    limits = ConnectionLimits(max_per_address=4, idle_s=60, request_s=60)
    with Server(holding_app(release), ServeSettings(port=0), limits=limits) as server:
        port = server.port
        assert port is not None
        answers = _burst(port, "127.0.0.5", 40, "/metrics")
        assert set(answers) <= {"200", "503"} and len(answers) == 40, answers
        assert "200" in answers
        peers += [holding(port, "127.0.0.4") for _ in range(4)]
        assert _burst(port, "127.0.0.4", 40, "/metrics") == ["503"] * 40
        release.set()
