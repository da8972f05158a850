"""The Host allow-list: an ASGI middleware refusing requests for a name this server is not.

A web page of another site can make a browser on the control-room network send requests to
this service under the page's own host name (DNS rebinding): the request comes from inside,
but its Host header is the other site's name. Such requests are answered 421 before any
route runs, HTTP and WebSocket alike. The names allowed (`allowed_hosts`) default to what a
client can legitimately use: the bound address, the loopback names and addresses, and when
bound to every interface (0.0.0.0, ::) the machine's names (its host name, its fully
qualified name) and its interfaces' addresses. `[serve] allowed_hosts` adds names (those
the DNS or a proxy gives the service); "*" allows any Host, "*.example.org" a domain's
names. A Host's port is ignored (the socket already chose it); a request without a Host
header (HTTP/1.0) is no browser's and is served; one with two Host headers is refused.
"""

from __future__ import annotations

import contextlib
import ipaddress
import json
import logging
import socket
from collections.abc import Iterable
from itertools import pairwise
from pathlib import Path

from starlette.types import ASGIApp, Receive, Scope, Send

logger = logging.getLogger(__name__)

LOOPBACK = ("localhost", "127.0.0.1", "::1")
WILDCARDS = ("0.0.0.0", "::", "")


def normal(host: str) -> str:
    """A host name or address as compared: lower case, no trailing dot, IPv6 without
    brackets, an address in its canonical form."""
    name = host.strip().lower().rstrip(".")
    if name.startswith("[") and name.endswith("]"):
        name = name[1:-1]
    with contextlib.suppress(ValueError):
        return str(ipaddress.ip_address(name))
    return name


def host_of(header: str) -> str:
    """The host of a Host header ("name", "name:port", "[v6]:port", "v6"), normalised."""
    value = header.strip()
    if value.startswith("["):
        end = value.find("]")
        return normal(value[: end + 1] if end > 0 else value)
    if value.count(":") == 1:  # name:port; more colons: a bare IPv6 address
        value = value.split(":", 1)[0]
    return normal(value)


def machine_names() -> set[str]:
    """This machine's names and the addresses they resolve to (no network beyond the
    resolver), and its interfaces' addresses."""
    names: set[str] = set()
    for get in (socket.gethostname, socket.getfqdn):
        with contextlib.suppress(OSError, UnicodeError):
            if name := get():
                names.add(normal(name))
    for name in list(names):
        with contextlib.suppress(OSError, UnicodeError):
            for *_, address in socket.getaddrinfo(name, None, type=socket.SOCK_STREAM):
                names.add(normal(str(address[0]).split("%", 1)[0]))
    return names | _interface_addresses()


def _interface_addresses() -> set[str]:
    """The IPv6 addresses of /proc/net/if_inet6 and the IPv4 ones of /proc/net/fib_trie's
    local entries (Linux; elsewhere none: configure allowed_hosts)."""
    found: set[str] = set()
    with contextlib.suppress(OSError, ValueError):
        for line in Path("/proc/net/if_inet6").read_text().splitlines():
            raw = line.split()[0]
            found.add(normal(":".join(raw[i : i + 4] for i in range(0, 32, 4))))
    with contextlib.suppress(OSError, ValueError):
        lines = Path("/proc/net/fib_trie").read_text().splitlines()
        for previous, line in pairwise(lines):
            if "/32 host LOCAL" in line and "|--" in previous:
                found.add(normal(previous.split("|--", 1)[1]))
    return found


def default_hosts(bound: str) -> set[str]:
    """The names a client may use for a server bound to `bound` (see the module)."""
    hosts = {normal(h) for h in LOOPBACK}
    if normal(bound) in {normal(w) for w in WILDCARDS if w}:
        hosts |= machine_names()
    elif bound:
        hosts.add(normal(bound))
    return hosts


def allowed_hosts(bound: str, configured: Iterable[str] = ()) -> tuple[str, ...]:
    """The allow-list of a server bound to `bound`: default_hosts and the `configured` names
    (the names a proxy or the DNS gives the service)."""
    return tuple(sorted(default_hosts(bound) | {normal(h) for h in configured}))


class HostCheck:
    """Requests (HTTP and WebSocket) whose Host is not in `allowed` answered 421."""

    def __init__(self, app: ASGIApp, allowed: Iterable[str]) -> None:
        self.app = app
        names = {normal(h) for h in allowed}
        self.any = "*" in names
        self.suffixes = tuple(n[1:] for n in names if n.startswith("*."))  # ".example.org"
        self.names = {n for n in names if not n.startswith("*")}
        self._warned: set[str] = set()

    def allows(self, host: str) -> bool:
        return self.any or host in self.names or host.endswith(self.suffixes or ("\0",))

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] not in ("http", "websocket"):
            await self.app(scope, receive, send)
            return
        values = [v for k, v in scope.get("headers", []) if k == b"host"]
        host = host_of(values[0].decode("latin-1")) if values else ""
        if not values or (len(values) == 1 and self.allows(host)):
            await self.app(scope, receive, send)
            return
        if host not in self._warned and len(self._warned) < 64:  # once per name, bounded
            self._warned.add(host)
            logger.warning("refused a request for host %r (not in serve.allowed_hosts)", host[:100])
        if scope["type"] == "websocket":
            await send({"type": "websocket.close", "code": 1008})
            return
        body = json.dumps({"detail": "unknown host: not a name of this server"}).encode()
        headers = [(b"content-type", b"application/json"), (b"content-length", b"%d" % len(body))]
        await send({"type": "http.response.start", "status": 421, "headers": headers})
        await send({"type": "http.response.body", "body": body})
