"""Connection places behind a NAT or a reverse proxy, against a real server on real loopback
addresses: a logged-in console keeps its connection whatever else comes from its address, a
trusted proxy's connections are not capped per address and the client address it forwards
counts for the login limits, and nobody else's X-Forwarded-For is believed."""

from __future__ import annotations

import json
import socket

import httpx
import pytest

from consoled import PASSWORDS, console_server
from stereopose.errors import ConfigError
from stereopose.login_limit import MAX_FAILURES
from stereopose.web.connections import ConnectionLimits
from stereopose.web.server import ServeSettings
from waiting import wait_until


class Raw:
    """One keep-alive HTTP/1.1 connection from a loopback `source` address."""

    def __init__(self, port: int, source: str) -> None:
        self.sock = socket.create_connection(
            ("127.0.0.1", port), timeout=10, source_address=(source, 0)
        )
        self.port = port

    def ask(
        self,
        method: str,
        path: str,
        body: dict | None = None,
        headers: dict[str, str] | None = None,
    ) -> tuple[int, dict, bytes]:
        data = json.dumps(body).encode() if body is not None else b""
        head = [
            f"{method} {path} HTTP/1.1",
            f"host: 127.0.0.1:{self.port}",
            f"content-length: {len(data)}",
        ]
        if body is not None:
            head.append("content-type: application/json")
        head += [f"{k}: {v}" for k, v in (headers or {}).items()]
        self.sock.sendall(("\r\n".join(head) + "\r\n\r\n").encode() + data)
        buf = b""
        while b"\r\n\r\n" not in buf:
            chunk = self.sock.recv(65536)
            if not chunk:
                raise ConnectionError("closed by the server")
            buf += chunk
        raw_head, rest = buf.split(b"\r\n\r\n", 1)
        lines = raw_head.decode("latin-1").split("\r\n")
        fields: dict = {}
        for line in lines[1:]:
            k, _, v = line.partition(":")
            fields.setdefault(k.strip().lower(), []).append(v.strip())
        length = int(fields.get("content-length", ["0"])[0])
        while len(rest) < length:
            rest += self.sock.recv(65536)
        return int(lines[0].split()[1]), fields, rest[:length]

    def close(self) -> None:
        self.sock.close()


def _idle(port: int, source: str) -> socket.socket:
    return socket.create_connection(("127.0.0.1", port), timeout=10, source_address=(source, 0))


def _closed(sock: socket.socket) -> bool:
    sock.setblocking(False)
    try:
        return sock.recv(1) == b""
    except BlockingIOError:
        return False
    except OSError:
        return True
    finally:
        sock.setblocking(True)


def test_a_logged_in_console_keeps_its_connection_behind_a_shared_address(tmp_path):
    limits = ConnectionLimits(max_per_address=4, idle_s=60.0)
    with console_server(tmp_path / "out", limits=limits) as s:
        console = Raw(s.server.port, "127.0.0.5")
        status, fields, _ = console.ask(
            "POST", "/api/login", {"username": "otto", "password": PASSWORDS["otto"]}
        )
        assert status == 200
        cookie = "; ".join(c.split(";", 1)[0] for c in fields["set-cookie"])
        status, _, body = console.ask("GET", "/api/me", headers={"cookie": cookie})
        assert status == 200 and json.loads(body)["username"] == "otto"
        # anonymous traffic from the same address, three times its cap: each newcomer takes
        # the place of an idle anonymous connection, never the console's
        others = [_idle(s.server.port, "127.0.0.5") for _ in range(12)]
        try:
            wait_until(
                lambda: sum(_closed(o) for o in others) >= 12 - 4,
                "the anonymous connections over the cap closed",
            )
            status, _, body = console.ask("GET", "/api/me", headers={"cookie": cookie})
            assert status == 200 and json.loads(body)["username"] == "otto"  # the same socket
        finally:
            for o in others:
                o.close()
            console.close()


def test_a_trusted_proxy_is_not_capped_and_its_forwarded_address_counts(tmp_path):
    limits = ConnectionLimits(max_per_address=4, idle_s=60.0)
    settings = ServeSettings(port=0, trusted_proxies=("127.0.0.7",))
    with console_server(tmp_path / "out", settings=settings, limits=limits) as s:
        port = s.server.port
        proxied = [_idle(port, "127.0.0.7") for _ in range(12)]
        direct = [_idle(port, "127.0.0.8") for _ in range(12)]
        try:
            wait_until(lambda: sum(_closed(d) for d in direct) >= 8, "the direct ones capped")
            assert not any(_closed(p) for p in proxied)  # the proxy's 12: all kept
        finally:
            for c in proxied + direct:
                c.close()

        def login(source: str, forwarded: str | None) -> int:
            headers = {"x-forwarded-for": forwarded} if forwarded else {}
            transport = httpx.HTTPTransport(local_address=source)
            with httpx.Client(base_url=s.url, transport=transport, timeout=30) as c:
                return c.post(
                    "/api/login", headers=headers, json={"username": "otto", "password": "wrong"}
                ).status_code

        for _ in range(MAX_FAILURES):
            assert login("127.0.0.7", "10.1.1.1") == 401
        assert login("127.0.0.7", "10.1.1.1") == 429  # that client, behind the proxy
        assert login("127.0.0.7", "10.1.1.2") == 401  # another client of the same proxy
        # anyone else's X-Forwarded-For is not believed: its own address counts
        for n in range(MAX_FAILURES):
            assert login("127.0.0.8", f"10.2.2.{n}") == 401
        assert login("127.0.0.8", "10.2.2.99") == 429


def test_trusted_proxies_are_checked():
    with pytest.raises(ConfigError, match="trusted_proxies"):
        ServeSettings(trusted_proxies=("not-an-address",))
    assert ServeSettings(trusted_proxies=("10.0.0.0/24", "::1")).trusted_proxies
