"""The HTTP server in its thread: a free port reported, a busy port refused by name, a
bounded shutdown with requests still open, the settings' checks."""

from __future__ import annotations

import asyncio
import contextlib
import re
import socket
import threading
from collections.abc import AsyncIterator

import pytest
from fastapi import FastAPI
from hypothesis import given
from hypothesis import strategies as st

from served import get, get_json
from stereopose.errors import ConfigError, StereoposeError
from stereopose.site.health.state import ServiceState
from stereopose.site.http.app import create_app
from stereopose.web.server import (
    MAX_CONNECTIONS,
    MAX_REQUESTS,
    ServeError,
    Server,
    ServerTimes,
    ServeSettings,
    bind,
    is_loopback,
)
from waiting import wait_until


def refused(port: int) -> bool:
    """Whether a connection to 127.0.0.1:port is refused (nothing listens)."""
    try:
        socket.create_connection(("127.0.0.1", port), timeout=2).close()
    except ConnectionRefusedError:
        return True
    return False


def stop_within(server: Server, timeout_s: float) -> list[bool]:
    """Stop `server` from another thread; fail unless it returns within timeout_s."""
    result: list[bool] = []
    threading.Thread(target=lambda: result.append(server.stop()), daemon=True).start()
    wait_until(lambda: bool(result), "the server's stop() to return", timeout_s=timeout_s)
    return result


def test_port_zero_gives_a_free_port_and_stop_frees_it():
    server = Server(create_app(ServiceState()), ServeSettings(port=0))
    port = server.start()
    assert port > 0 and server.url == f"http://127.0.0.1:{port}"
    assert get_json(server.url + "/api/health")[0] == 503
    assert stop_within(server, 10) == [True]
    assert refused(port)
    again = Server(create_app(ServiceState()), ServeSettings(port=port))  # the same port again
    with again:
        assert get(again.url + "/metrics")[0] == 200
    assert server.stop()  # a second stop does nothing


def test_a_busy_port_is_an_error_naming_host_and_port():
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        server = Server(create_app(ServiceState()), ServeSettings(port=port))
        with pytest.raises(ServeError, match=rf"cannot listen on 127\.0\.0\.1:{port}: .*in use"):
            server.start()
    assert issubclass(ServeError, StereoposeError)


def test_a_host_that_is_not_this_machine_is_an_error():
    with pytest.raises(ServeError, match=r"cannot listen on 192\.0\.2\.1:0"):
        bind(ServeSettings(host="192.0.2.1", port=0))  # TEST-NET-1: no interface has it
    with pytest.raises(ServeError, match=r"cannot listen on no-such-host\.invalid:0"):
        bind(ServeSettings(host="no-such-host.invalid", port=0))


def test_local_only_refuses_an_address_others_can_reach():
    app = create_app(ServiceState())
    with pytest.raises(ServeError, match=r"serve.host '0.0.0.0'.*loopback.*0\.0\.0\.0:0"):
        Server(app, ServeSettings(host="0.0.0.0", port=0), local_only=True).start()
    with Server(app, ServeSettings(host="localhost", port=0), local_only=True) as server:
        assert get(server.url + "/metrics")[0] == 200
    with Server(app, ServeSettings(host="0.0.0.0", port=0)) as server:  # when not told: allowed
        assert get(f"http://127.0.0.1:{server.port}/metrics")[0] == 200


@pytest.mark.parametrize(
    ("host", "loopback"),
    [
        ("127.0.0.1", True),
        ("127.1.2.3", True),
        ("::1", True),
        ("localhost", True),
        ("LOCALHOST.", True),
        ("0.0.0.0", False),
        ("::", False),
        ("10.0.0.5", False),
        ("example.org", False),
    ],
)
def test_is_loopback(host: str, loopback: bool):
    assert is_loopback(host) is loopback


def test_shutdown_is_bounded_with_requests_still_open(caplog):
    app = create_app(ServiceState())
    entered, release = threading.Event(), threading.Event()

    @app.get("/api/slow")
    async def slow() -> dict:  # an answer that would never come
        entered.set()
        await asyncio.sleep(3600)
        return {}

    @app.get("/api/stuck")
    def stuck() -> dict:  # a thread-pool route blocked on something outside
        entered.set()
        release.wait(30)
        return {}

    for path in ("/api/slow", "/api/stuck"):
        entered.clear()
        server = Server(
            app, ServeSettings(port=0), times=ServerTimes(graceful_s=0.2, shutdown_timeout_s=1.0)
        )
        port = server.start()
        idle = socket.create_connection(("127.0.0.1", port))  # a keep-alive client, silent
        threading.Thread(target=get, args=(server.url + path,), daemon=True).start()
        wait_until(entered.is_set, f"{path} to be running")
        stop_within(server, 10)  # within shutdown_timeout_s + 1 s, forced if it must be
        assert refused(port)
        idle.close()
        release.set()
        thread = server._thread
        assert thread is not None
        wait_until(lambda t=thread: not t.is_alive(), "the server thread to end")
    cancelled = [r for r in caplog.records if "cancelled" in r.getMessage()]
    assert cancelled and all(r.exc_info is None for r in caplog.records)  # a line, no traceback


def test_a_failing_startup_is_an_error_and_frees_the_port():
    @contextlib.asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        raise OSError("the frame loop could not start")
        yield

    server = Server(create_app(ServiceState(), lifespan=lifespan), ServeSettings(port=0))
    with pytest.raises(ServeError, match=r"127\.0\.0\.1:\d+ stopped while starting.*startup"):
        server.start()
    assert server.port is not None and refused(server.port)


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("port", -1),
        ("port", 65536),
        ("port", 8080.0),
        ("port", "8080"),
        ("port", True),
        ("host", ""),
        ("host", "a b"),
        ("host", "-bad.example"),
        ("host", "x" * 300),
        ("host", "exa_mple"),
        ("host", None),
        ("host", "http://127.0.0.1"),
    ],
)
def test_bad_settings_name_serve_key_and_value(field: str, value: object):
    with pytest.raises(ConfigError, match=rf"serve\.{field} .*got {re.escape(repr(value))}"):
        ServeSettings(**{field: value})  # type: ignore[arg-type]


@given(
    port=st.one_of(st.integers(), st.floats(), st.text(max_size=6), st.none()),
    host=st.one_of(st.text(max_size=20), st.ip_addresses().map(str)),
)
def test_settings_are_valid_or_a_config_error(port: object, host: str):
    try:
        s = ServeSettings(host=host, port=port)  # type: ignore[arg-type]
    except ConfigError as e:
        assert str(e).startswith(("serve.host ", "serve.port "))
        return
    assert isinstance(s.port, int) and 0 <= s.port <= 65535 and s.host == host


def test_idle_connections_up_to_the_caps_leave_the_server_answering():
    # the caps (web.connections): idle connections do not count as answers in progress
    assert MAX_CONNECTIONS > MAX_REQUESTS == 64
    with Server(create_app(ServiceState()), ServeSettings(port=0)) as server:
        idle = []
        try:
            for i in range(MAX_REQUESTS):  # 16 from each of 4 loopback addresses
                s = socket.socket()
                s.bind((f"127.0.0.{2 + i // 16}", 0))
                s.connect(("127.0.0.1", server.port))
                idle.append(s)
            assert get(server.url + "/metrics")[0] == 200
        finally:
            for s in idle:
                s.close()
