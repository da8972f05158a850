"""Run the service's HTTP app with uvicorn in a background thread, with a bounded shutdown.

The listening socket is bound in the caller's thread, so a busy port or a bad address is a
ServeError (a StereoposeError naming host:port) raised by `start()`, and port 0 gives a free
port that `start()` returns. uvicorn is set for a closed network: no Server header, no
X-Forwarded-* trusted but from [serve] trusted_proxies, its logging left to the application
(no dictConfig of its own),
signals left to the caller; its h11 protocol is web.connections' (timeouts for idle and
slow connections, request heads bounded, caps per client address and in all, health always
served; `Server(limits=ConnectionLimits(...))` changes them).
With a certificate and its key (ServeSettings), it speaks HTTPS only. Told how to count the
console's users (`Server(users=...)`), it refuses to listen on an address other machines can
reach while there is no user: the console would be open to nobody, and a first user is
added on the machine itself (`stereopose users add`).
"""

from __future__ import annotations

import asyncio
import dataclasses
import ipaddress
import logging
import re
import socket
import ssl
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

import uvicorn

from stereopose.errors import ConfigError, StereoposeError
from stereopose.web.connections import MAX_HEADER_BYTES as MAX_HEADER_BYTES  # re-exported
from stereopose.web.connections import ConnectionLimits, guarded_protocol

logger = logging.getLogger(__name__)

MAX_REQUESTS = ConnectionLimits.max_requests  # answers in progress; beyond them 503
MAX_CONNECTIONS = ConnectionLimits.max_connections  # open at once (the longest waiting gives way)
KEEP_ALIVE_S = ConnectionLimits.idle_s
GRACEFUL_S = 3  # open requests get this long at shutdown, then are cancelled

_HOSTNAME = re.compile(r"(?!-)[A-Za-z0-9-]{1,63}(?<!-)(\.(?!-)[A-Za-z0-9-]{1,63}(?<!-))*\.?")


class _CancelledQuietly(logging.Filter):
    """uvicorn logs a request cancelled at shutdown (graceful_s over) with a traceback, as if
    the app had failed; one line says what happened."""

    def filter(self, record: logging.LogRecord) -> bool:
        if record.exc_info and isinstance(record.exc_info[1], asyncio.CancelledError):
            record.msg, record.args = "a request still open at shutdown was cancelled", ()
            record.exc_info, record.exc_text, record.levelno = None, None, logging.WARNING
            record.levelname = "WARNING"
        return True


_UVICORN_LOG = logging.getLogger("uvicorn.error")
if not any(isinstance(f, _CancelledQuietly) for f in _UVICORN_LOG.filters):
    _UVICORN_LOG.addFilter(_CancelledQuietly())


class ServeError(StereoposeError):
    """The HTTP server cannot start (address busy or not this machine's, or not allowed)."""


@dataclass(frozen=True)
class ServeSettings:
    """Where the HTTP server listens. host: an IP address or host name ("0.0.0.0": every
    interface); port: 0 to 65535 (0: any free port); certificate, key: PEM files (both or
    neither): HTTPS."""

    host: str = "127.0.0.1"
    port: int = 8787
    certificate: str | None = None
    key: str | None = None
    trusted_proxies: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        host = self.host
        if not isinstance(host, str) or not host or len(host) > 253 or not _is_host(host):
            raise ConfigError(f"serve.host must be an IP address or a host name, got {host!r}")
        port = self.port
        if isinstance(port, bool) or not isinstance(port, int) or not 0 <= port <= 65535:
            raise ConfigError(f"serve.port must be an integer in [0, 65535], got {port!r}")
        if (self.certificate is None) != (self.key is None):
            raise ConfigError("serve.certificate and serve.key: give both (HTTPS) or neither")
        for proxy in self.trusted_proxies:
            try:
                ipaddress.ip_network(proxy, strict=False)
            except ValueError:
                raise ConfigError(
                    f"serve.trusted_proxies: expected an IP address or network, got {proxy!r}"
                ) from None

    @property
    def tls(self) -> bool:
        return self.certificate is not None


def _is_host(host: str) -> bool:
    try:
        ipaddress.ip_address(host)
        return True
    except ValueError:
        return _HOSTNAME.fullmatch(host) is not None


def is_loopback(host: str) -> bool:
    """Whether `host` is this machine only: "localhost" or a loopback address."""
    if host.lower().rstrip(".") == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def _where(host: str, port: int) -> str:
    return f"[{host}]:{port}" if ":" in host else f"{host}:{port}"


def bind(settings: ServeSettings, *, local_only: bool = False) -> socket.socket:
    """A socket bound to settings.host:port (not yet listening). local_only: refuse an address
    that other machines could reach. Raises ServeError naming host:port and the reason."""
    host, port = settings.host, settings.port
    where = _where(host, port)
    if local_only and not is_loopback(host):
        raise ServeError(
            f"serve.host {host!r}: only a loopback address (127.0.0.1, ::1, localhost) is "
            f"allowed here, got {where}"
        )
    try:
        candidates = socket.getaddrinfo(
            host, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE
        )
    except (socket.gaierror, UnicodeError) as e:
        raise ServeError(f"cannot listen on {where}: the host is not known ({e})") from None
    first: OSError | None = None
    for family, kind, proto, _, address in candidates:  # "localhost": ::1 may be missing
        sock = socket.socket(family, kind, proto)
        try:
            # a port left in TIME_WAIT by the previous run is reusable; one in use is not (Linux)
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            sock.bind(address)
        except OSError as e:
            sock.close()
            first = first or e
            continue
        return sock
    why = (first.strerror or str(first)) if first else "no address"
    raise ServeError(f"cannot listen on {where}: {why}")


def uvicorn_config(
    app: Callable[..., object],
    host: str,
    port: int,
    graceful_s: float = GRACEFUL_S,
    certificate: str | None = None,
    key: str | None = None,
    limits: ConnectionLimits | None = None,
    trusted_proxies: tuple[str, ...] = (),
) -> uvicorn.Config:
    """uvicorn's settings for the service (see the module docstring); trusted_proxies: the
    only peers whose X-Forwarded-For and X-Forwarded-Proto are believed."""
    limits = limits or ConnectionLimits()
    if trusted_proxies:
        limits = dataclasses.replace(limits, trusted_proxies=tuple(trusted_proxies))
    return uvicorn.Config(
        app,
        host=host,
        port=port,
        http=guarded_protocol(limits),
        ws="none",  # no route takes a websocket yet
        lifespan="on",
        log_config=None,
        access_log=False,
        server_header=False,
        proxy_headers=bool(trusted_proxies),
        forwarded_allow_ips=list(trusted_proxies) or None,
        limit_concurrency=None,  # counted by the protocol: answers in progress, not connections
        # uvicorn annotates whole seconds; it waits fractions as well
        timeout_keep_alive=limits.idle_s,  # pyright: ignore[reportArgumentType]
        timeout_graceful_shutdown=graceful_s,  # pyright: ignore[reportArgumentType]
        h11_max_incomplete_event_size=limits.max_header_bytes,
        ssl_certfile=certificate,
        ssl_keyfile=key,
    )


@dataclass(frozen=True)
class ServerTimes:
    """start_timeout_s: the most `start()` waits for the server to accept; shutdown_timeout_s:
    the most `stop()` takes; graceful_s: how long open requests may finish at shutdown."""

    start_timeout_s: float = 10.0
    shutdown_timeout_s: float = 5.0
    graceful_s: float = GRACEFUL_S


class Server:
    """The app served from a background thread. `start()` binds, serves and returns the bound
    port once the server accepts connections; `stop()` ends it (see ServerTimes). users: the
    number of console users now (None: not checked), and users_hint: how to add one, for the
    refusal to listen beyond this machine without any; limits: what one connection and one
    client address may hold (web.connections; None: its defaults). Usable as a context
    manager."""

    def __init__(
        self,
        app: Callable[..., object],
        settings: ServeSettings | None = None,
        *,
        local_only: bool = False,
        times: ServerTimes = ServerTimes(),
        users: Callable[[], int] | None = None,
        users_hint: str = "stereopose users add NAME --role admin --config CONFIG.toml",
        limits: ConnectionLimits | None = None,
    ) -> None:
        self.app = app
        self.limits = limits or ConnectionLimits()
        self.users, self.users_hint = users, users_hint
        self.settings = settings or ServeSettings()
        self.local_only = local_only
        self.start_timeout_s = times.start_timeout_s
        self.shutdown_timeout_s = times.shutdown_timeout_s
        self.graceful_s = times.graceful_s
        self.port: int | None = None
        self._server: uvicorn.Server | None = None
        self._thread: threading.Thread | None = None
        self._sock: socket.socket | None = None
        self._failure: BaseException | None = None

    @property
    def url(self) -> str:
        """http(s)://host:port of the running server."""
        if self.port is None:
            raise RuntimeError("the server is not started")
        scheme = "https" if self.settings.tls else "http"
        return f"{scheme}://{_where(self.settings.host, self.port)}"

    def start(self) -> int:
        """Bind, serve in a thread, wait until it accepts; the bound port."""
        if self._thread is not None:
            raise RuntimeError("the server is already started")
        self._check_users()
        sock = bind(self.settings, local_only=self.local_only)
        self._sock = sock
        port: int = sock.getsockname()[1]
        self.port = port
        where = _where(self.settings.host, port)
        s = self.settings
        try:
            config = uvicorn_config(
                self.app,
                s.host,
                port,
                self.graceful_s,
                s.certificate,
                s.key,
                self.limits,
                s.trusted_proxies,
            )
            config.load()  # the certificate and key read now: a bad one is a ServeError
        except (OSError, ssl.SSLError) as e:
            self._close_socket()
            raise ServeError(
                f"cannot serve HTTPS on {where} with serve.certificate "
                f"{s.certificate} and serve.key {s.key}: {e}"
            ) from None
        self._server = uvicorn.Server(config)
        self._thread = threading.Thread(target=self._serve, name=f"http {where}", daemon=True)
        self._thread.start()
        deadline = time.monotonic() + self.start_timeout_s
        while not self._server.started:
            if not self._thread.is_alive():
                self._close_socket()
                why = f": {self._failure}" if self._failure else ""
                raise ServeError(f"the HTTP server on {where} stopped while starting{why}")
            if time.monotonic() > deadline:
                self.stop()
                raise ServeError(
                    f"the HTTP server on {where} did not start within {self.start_timeout_s:g} s"
                )
            time.sleep(0.01)
        logger.info("HTTP server listening on %s", self.url)
        return port

    def _check_users(self) -> None:
        host = self.settings.host
        if self.users is None or is_loopback(host):
            return
        try:
            n = self.users()
        except StereoposeError as e:
            raise ServeError(f"serve.host {host!r}: cannot read the console's users: {e}") from None
        if n == 0:
            raise ServeError(
                f"serve.host {host!r} is reachable from other machines, and the console has no "
                f"user yet: add one first with `{self.users_hint}` (the password is read from "
                "standard input), or serve on 127.0.0.1"
            )

    def stop(self) -> bool:
        """Stop serving: new connections refused at once, open requests given graceful_s,
        then cancelled; returns within shutdown_timeout_s (plus 1 s if it must be forced).
        Whether the server thread ended."""
        server, thread = self._server, self._thread
        if server is None or thread is None:
            return True
        server.should_exit = True
        thread.join(self.shutdown_timeout_s)
        if thread.is_alive():
            logger.warning(
                "the HTTP server did not stop within %g s; forcing it", self.shutdown_timeout_s
            )
            server.force_exit = True
            thread.join(1.0)
        self._close_socket()
        ended = not thread.is_alive()
        if not ended:
            logger.error("the HTTP server thread is still running; left to end with the process")
        return ended

    def _serve(self) -> None:
        assert self._server is not None and self._sock is not None
        try:
            self._server.run(sockets=[self._sock])
        except SystemExit:  # uvicorn's way to say the app's startup failed (logged by it)
            self._failure = RuntimeError("the app's startup failed (see the log)")
        except BaseException as e:
            self._failure = e
            logger.exception("the HTTP server stopped")

    def _close_socket(self) -> None:
        if self._sock is not None:
            self._sock.close()

    def __enter__(self) -> Server:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()
