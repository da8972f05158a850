"""Connections that cannot be held: uvicorn's h11 protocol with the timeouts and caps it lacks.

uvicorn arms no timer before a connection's first request, and none while it reads a request,
so a silent connection or a slow sender (slowloris) is kept for ever; its concurrency limit
counts idle connections, so 64 of them answer every request 503, /api/health included; and
h11's `max_incomplete_event_size` bounds only a request head still incomplete, so one that
arrives whole in one read (60 kB) is parsed whatever its size. `guarded_protocol(limits)`
gives the protocol class (`uvicorn.Config(http=...)`) that closes these, per server:

- a connection that sends nothing for `idle_s` after it opens is closed (between requests,
  uvicorn's keep-alive timeout does the same, set to `idle_s` by web.server);
- a request (its line, headers and body) must arrive within `request_s` of its first byte,
  or of the connection's opening for the first request: else 408 and closed;
- a request head (line + headers) over `max_header_bytes` is answered 431 and closed, before
  anything parses it;
- at most `max_per_address` connections from one client address (an IPv6 one: its /64)
  and `max_connections` in all: a new one beyond either takes the place of the
  longest-waiting connection with no answer in progress (of that address, or of any: it is
  answered 503), and is refused (503) only when every place is busy answering; a connection
  turned away is answered, half-closed and read (what comes dropped) for LINGER_S before it
  closes, so its client reads the answer and never meets a TCP reset; an answer being
  streamed (live channel, clip player) is never closed for it, nor a connection that has
  carried a logged-in request (it has a place of its own, outside its address's cap:
  operators behind one NAT share an address); a trusted reverse proxy's address
  (`trusted_proxies`) is not capped per address;
- at most `max_requests` answers in progress (streams included); beyond it 503, while
  /api/health and /metrics have `health_reserve` places more.

Every refusal and closing is counted (`ConnectionTable.counts`) and logged at most once per
LOG_EVERY_S per kind.
"""

from __future__ import annotations

import asyncio
import ipaddress
import logging
import re
import time
from collections import Counter
from dataclasses import dataclass, field
from http import HTTPStatus
from ipaddress import IPv4Network, IPv6Network
from typing import Any, ClassVar

import h11
from starlette.types import ASGIApp, Message, Receive, Scope, Send
from uvicorn.config import Config
from uvicorn.protocols.http.h11_impl import H11Protocol
from uvicorn.server import ServerState

from stereopose.errors import ConfigError

logger = logging.getLogger(__name__)

MAX_HEADER_BYTES = 16 * 1024  # request line + headers; a browser sends a few KiB at most
HEALTH_PATHS = frozenset({"/api/health", "/metrics"})
LOG_EVERY_S = 10.0
_HEAD_END = re.compile(rb"\n\r?\n")  # where h11 ends a request head (a bare newline too)


@dataclass(frozen=True)
class ConnectionLimits:
    """What one client may hold (see the module docstring); times in seconds."""

    max_connections: int = 256
    max_per_address: int = 16
    max_requests: int = 64
    health_reserve: int = 8
    idle_s: float = 5.0
    request_s: float = 10.0
    max_header_bytes: int = MAX_HEADER_BYTES
    # reverse proxies (addresses or networks): not capped per address, every client behind
    # one comes from its address
    trusted_proxies: tuple[str, ...] = ()
    # trusted_proxies read as networks (__post_init__)
    _proxies: tuple[IPv4Network | IPv6Network, ...] = field(
        default=(), init=False, repr=False, compare=False
    )

    def __post_init__(self) -> None:
        for name, value in (
            ("max_connections", self.max_connections),
            ("max_per_address", self.max_per_address),
            ("max_requests", self.max_requests),
            ("max_header_bytes", self.max_header_bytes),
        ):
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ConfigError(
                    f"connection limits: {name} must be an integer >= 1, got {value!r}"
                )
        if (
            isinstance(self.health_reserve, bool)
            or not isinstance(self.health_reserve, int)
            or self.health_reserve < 0
        ):
            raise ConfigError(
                f"connection limits: health_reserve must be an integer >= 0, "
                f"got {self.health_reserve!r}"
            )
        if self.max_connections <= self.max_requests + self.health_reserve:
            raise ConfigError(  # a place for health always: busy connections are at most these
                "connection limits: max_connections must be above max_requests + "
                f"health_reserve, got {self.max_connections} <= "
                f"{self.max_requests} + {self.health_reserve}"
            )
        try:
            nets = tuple(ipaddress.ip_network(p, strict=False) for p in self.trusted_proxies)
        except (TypeError, ValueError):
            raise ConfigError(
                f"connection limits: trusted_proxies must be IP addresses or "
                f"networks, got {self.trusted_proxies!r}"
            ) from None
        object.__setattr__(self, "_proxies", nets)
        for name, value in (("idle_s", self.idle_s), ("request_s", self.request_s)):
            if isinstance(value, bool) or not isinstance(value, int | float) or not value > 0:
                raise ConfigError(f"connection limits: {name} must be a number > 0, got {value!r}")


def is_trusted_proxy(limits: ConnectionLimits, host: str) -> bool:
    """Whether `host` is one of the limits' trusted reverse proxies."""
    try:
        ip = ipaddress.ip_address(host)
    except ValueError:
        return False
    if isinstance(ip, ipaddress.IPv6Address) and ip.ipv4_mapped is not None:
        ip = ip.ipv4_mapped
    return any(ip in net for net in limits._proxies)


def client_key(host: str) -> str:
    """The client address a connection counts against: an IPv6 host has a /64 of its own
    (one address each would give it millions of places), an IPv4-mapped one is its IPv4."""
    try:
        ip = ipaddress.ip_address(host)
    except ValueError:
        return host
    if isinstance(ip, ipaddress.IPv6Address):
        if ip.ipv4_mapped is not None:
            return str(ip.ipv4_mapped)
        if not ip.is_loopback:
            return str(ipaddress.IPv6Network((ip, 64), strict=False))
    return str(ip)


class ConnectionTable:
    """The open connections of one server, by client address, and what was refused.

    A connection that has carried a logged-in request (`logged_in`) has a place of its own:
    it no longer counts against its address's cap, and a new connection never takes its
    place (operators behind one NAT or proxy share an address with whatever else comes from
    it). `by_address` counts the other connections."""

    def __init__(self) -> None:
        self.open: dict[GuardedH11Protocol, str] = {}
        self.by_address: Counter[str] = Counter()
        self.sessions: set[GuardedH11Protocol] = set()
        self.counts: Counter[str] = Counter()  # refused/closed, by reason
        self._logged: dict[str, float] = {}

    def add(self, conn: GuardedH11Protocol, address: str) -> None:
        self.open[conn] = address
        self.by_address[address] += 1

    def _uncount(self, address: str) -> None:
        self.by_address[address] -= 1
        if self.by_address[address] <= 0:
            del self.by_address[address]

    def logged_in(self, conn: GuardedH11Protocol) -> None:
        """`conn` carried a request of a live session: a place of its own from now on."""
        address = self.open.get(conn)
        if address is not None and conn not in self.sessions:
            self.sessions.add(conn)
            self._uncount(address)

    def remove(self, conn: GuardedH11Protocol) -> None:
        address = self.open.pop(conn, None)
        if address is None:
            return
        if conn in self.sessions:
            self.sessions.discard(conn)
        else:
            self._uncount(address)

    def longest_waiting(self, address: str | None = None) -> GuardedH11Protocol | None:
        """The connection (of `address`, or any) waiting longest with no answer in progress,
        of those without a session: a logged-in console is never closed for a newcomer."""
        waiting = [
            c
            for c, a in self.open.items()
            if (address is None or a == address) and c not in self.sessions and c.waiting()
        ]
        return min(waiting, key=lambda c: c.waiting_since, default=None)

    def note(self, reason: str, what: str) -> None:
        """Count one refusal or closing; log it unless this reason was logged just now."""
        self.counts[reason] += 1
        now = time.monotonic()
        if now - self._logged.get(reason, -LOG_EVERY_S) >= LOG_EVERY_S:
            self._logged[reason] = now
            logger.warning("%s (%d so far)", what, self.counts[reason])


RETRY_AFTER_S = 1  # a refused connection or request may come back this soon
# a connection turned away stays open this long after its answer, reading (and dropping) what
# its client still sends: closed at once, the request arriving after the close would make the
# kernel reset it, and the client would lose the answer
LINGER_S = 2.0


def _raw_answer(status: int, text: str) -> bytes:
    """An answer written past h11 (which sends none before a request is whole); a 503 says
    when to come back."""
    body, reason = text.encode(), HTTPStatus(status).phrase.encode()
    retry = b"retry-after: %d\r\n" % RETRY_AFTER_S if status == 503 else b""
    return (
        b"HTTP/1.1 %d %s\r\ncontent-type: text/plain; charset=utf-8\r\n%s"
        b"content-length: %d\r\nconnection: close\r\n\r\n%s"
        % (status, reason, retry, len(body), body)
    )


async def _busy(send: Send) -> None:
    """503 with Retry-After: more answers in progress than the server takes."""
    body = b"too many requests in progress; try again in a moment"
    await send(
        {
            "type": "http.response.start",
            "status": 503,
            "headers": [
                (b"content-type", b"text/plain; charset=utf-8"),
                (b"content-length", b"%d" % len(body)),
                (b"retry-after", b"%d" % RETRY_AFTER_S),
                (b"connection", b"close"),
            ],
        }
    )
    await send({"type": "http.response.body", "body": body})


class _Admission:
    """Answers in progress bounded (503 beyond), with places kept for health and metrics; a
    request the app found logged in (its scope's state holds a session, web.auth) gives
    its connection a place of its own (ConnectionTable.logged_in)."""

    def __init__(
        self,
        app: ASGIApp,
        tasks: set[Any],
        limits: ConnectionLimits,
        table: ConnectionTable,
        conn: GuardedH11Protocol,
    ) -> None:
        self.app, self.tasks, self.limits, self.table = app, tasks, limits, table
        self.conn = conn

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        room = self.limits.max_requests  # this request's own task is among self.tasks
        if scope["path"] in HEALTH_PATHS:
            room += self.limits.health_reserve
        if len(self.tasks) > room:
            self.table.note("busy", f"more than {room} requests in progress: answered 503")
            await _busy(send)
            return

        async def marking_send(message: Message) -> None:
            if message["type"] == "http.response.start":
                state = scope.get("state")
                if isinstance(state, dict) and state.get("session") is not None:
                    self.table.logged_in(self.conn)
            await send(message)

        await self.app(scope, receive, marking_send)


class GuardedH11Protocol(H11Protocol):
    """uvicorn's h11 protocol with the timeouts and caps of the module docstring; a subclass
    per server (guarded_protocol) holds its limits and its table."""

    limits: ClassVar[ConnectionLimits] = ConnectionLimits()
    table: ClassVar[ConnectionTable] = ConnectionTable()

    def __init__(
        self,
        config: Config,
        server_state: ServerState,
        app_state: dict[str, Any],
        _loop: asyncio.AbstractEventLoop | None = None,
    ) -> None:
        super().__init__(config, server_state, app_state, _loop)
        self.app = _Admission(self.app, server_state.tasks, self.limits, self.table, self)
        self.waiting_since = time.monotonic()  # since when no answer is in progress
        self._timer: asyncio.TimerHandle | None = None
        self._reading = False  # a request's first byte came, the request is not whole yet
        self._deadline = 0.0  # loop time by which the request being read must be whole
        self._lingering = False  # answered and turned away: what comes is dropped until closed

    def waiting(self) -> bool:
        """No answer in progress: idle, or reading a request."""
        return (
            not self.transport.is_closing()
            and not self._lingering
            and (self.cycle is None or self.cycle.response_complete)
        )

    def connection_made(self, transport: asyncio.Transport) -> None:
        super().connection_made(transport)
        limits, table = self.limits, self.table
        host = self.client[0] if self.client else ""
        address = client_key(host)
        capped = not is_trusted_proxy(limits, host)  # a proxy's clients come from its address
        if (
            capped
            and table.by_address[address] >= limits.max_per_address
            and not self._take_place(
                address, f"more than {limits.max_per_address} connections from {address}"
            )
        ):
            self._refuse(
                503,
                "too many connections from this address",
                "address",
                f"{address}: every connection of it busy, one refused",
            )
            return
        if len(table.open) >= limits.max_connections and not self._take_place(
            None, f"more than {limits.max_connections} connections"
        ):
            self._refuse(
                503,
                "too many connections",
                "full",
                f"all {limits.max_connections} connections busy, one refused",
            )
            return
        table.add(self, address)
        # nothing sent within idle_s: closed; the first request whole within request_s
        self._arm(min(limits.idle_s, limits.request_s))
        self._deadline = self.loop.time() + limits.request_s

    def _take_place(self, address: str | None, why: str) -> bool:
        """Close the longest-waiting connection (of `address`, or any) for a new one."""
        oldest = self.table.longest_waiting(address)
        if oldest is None:
            return False
        self.table.note("evicted", f"{why}: the longest waiting closed for a new one")
        oldest._turn_away(503, "too many connections from this client; try again in a moment")
        self.table.remove(oldest)  # its place is free now, before its connection_lost
        return True

    def connection_lost(self, exc: Exception | None) -> None:
        self._cancel()
        self.table.remove(self)
        super().connection_lost(exc)

    def data_received(self, data: bytes) -> None:
        if self.transport.is_closing() or self._lingering:
            return
        if self.conn.their_state is h11.IDLE:  # a request's line and headers
            if not self._reading:
                self._start_reading()
            if self._head_over(data):
                return
        super().data_received(data)
        self._check_read()

    def on_response_complete(self) -> None:
        self.waiting_since = time.monotonic()
        if self.transport.is_closing():
            super().on_response_complete()
            return
        if self.conn.our_state is h11.DONE and self.conn.their_state is h11.DONE:
            following = self.conn.trailing_data[0]  # a pipelined request, read already
            if following and self._head_over(b""):
                return
        super().on_response_complete()
        if self.conn.their_state is h11.IDLE and self.conn.trailing_data[0]:
            self._start_reading()  # part of the next request is here: its clock runs
        self._check_read()

    def _start_reading(self) -> None:
        self._reading = True
        if self.cycle is not None:  # a later request: from its first byte (the first: opening)
            self._deadline = self.loop.time() + self.limits.request_s
        self._arm(self._deadline - self.loop.time())

    def _check_read(self) -> None:
        """The request read whole (or the connection done): its timer stops."""
        if self._reading and self.conn.their_state not in (h11.IDLE, h11.SEND_BODY):
            self._reading = False
            self._cancel()

    def _head_over(self, data: bytes) -> bool:
        """Whether the request head (buffered + data) is whole and over the limit, or frames
        its body twice; if so it is answered (431, 400) and the connection closed. An
        incomplete one is bounded by h11."""
        pending = self.conn.trailing_data[0] + data  # at most the limit + one read
        end = _HEAD_END.search(pending)
        if end is None:
            return False
        limit = self.limits.max_header_bytes
        if end.end() > limit:
            self._refuse(
                431,
                f"request line and headers over {limit} bytes",
                "header",
                f"a request head of {end.end()} bytes (over {limit}) refused",
            )
            return True
        names = {
            line.split(b":", 1)[0].strip().lower()
            for line in pending[: end.start()].split(b"\n")[1:]
        }
        if b"content-length" in names and b"transfer-encoding" in names:
            # RFC 9112 6.1: a request framed both ways may smuggle a second one in its body
            self._refuse(
                400,
                "Content-Length and Transfer-Encoding together",
                "smuggling",
                "a request with both Content-Length and Transfer-Encoding refused, "
                "its connection closed",
            )
            return True
        return False

    def _arm(self, delay_s: float) -> None:
        self._cancel()
        self._timer = self.loop.call_later(max(delay_s, 0.0), self._timed_out)

    def _cancel(self) -> None:
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None

    def _timed_out(self) -> None:
        self._timer = None
        if self.transport.is_closing():
            return
        if not self._reading:
            # only the opening's timer runs while no request is read (then uvicorn's keep-alive)
            silent = min(self.limits.idle_s, self.limits.request_s)
            self.table.note("idle", f"a connection silent for {silent:g} s closed")
            self._close()
        elif self.conn.their_state is h11.IDLE:  # its head incomplete: nothing answered yet
            within = f"{self.limits.request_s:g} s"
            self._refuse(
                408,
                "request not received in time",
                "slow",
                f"a request not whole within {within}: closed",
            )
        else:  # its body too slow: an answer may be under way, none can be written now
            self.table.note(
                "slow", f"a request body not whole within {self.limits.request_s:g} s: closed"
            )
            self._close()

    def _refuse(self, status: int, text: str, kind: str, what: str) -> None:
        """Answer `status` (connection: close) and close; counted as `kind`."""
        self.table.note(kind, what)
        self._turn_away(status, text)

    def _turn_away(self, status: int, text: str) -> None:
        """Answer `status` (connection: close, a 503 with Retry-After), end the sending side
        and close after LINGER_S or when the client closes, dropping what it still sends: the
        client reads the answer, never a reset."""
        self._cancel()
        self._reading, self._lingering = False, True
        if self.cycle is not None and not self.cycle.response_complete:
            self.cycle.keep_alive = False
        transport = self.transport
        transport.write(_raw_answer(status, text))
        if transport.can_write_eof():  # (TLS cannot half-close: its client closes, told to)
            transport.write_eof()
        self._timer = self.loop.call_later(LINGER_S, transport.close)

    def _close(self) -> None:
        self._cancel()
        self._reading = False
        if self.cycle is not None and not self.cycle.response_complete:
            self.cycle.keep_alive = False
        self.transport.close()


def guarded_protocol(limits: ConnectionLimits) -> type[GuardedH11Protocol]:
    """A protocol class for one server: `limits`, and a table of its own connections."""
    return type(
        "GuardedH11Protocol", (GuardedH11Protocol,), {"limits": limits, "table": ConnectionTable()}
    )
