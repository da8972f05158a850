"""The IEC 60870-5-104 outstation's settings (from [iec104]: who may connect, how many, the
time tags' clock, the link's timers) and the small helpers of its c104 server."""

from __future__ import annotations

import datetime as dt
import ipaddress
import socket
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from stereopose.config.scada import Iec104Config
from stereopose.errors import StereoposeError

__all__ = ["Iec104Error", "Iec104Settings"]


def _free_loopback_port() -> int:
    """A TCP port free on 127.0.0.1 now (for c104's server, behind the guard)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def typed_callback(fn: Callable, *, ret: Any, **params: Any) -> Callable:
    """`fn` with the annotations c104 checks a callback's signature against (as objects: this
    module's postponed annotations would be strings)."""
    fn.__annotations__ = {**params, "return": ret}
    return fn


class Iec104Error(StereoposeError):
    """The outstation cannot start (its port taken, c104 missing)."""


@dataclass(frozen=True)
class Iec104Settings:
    """What the outstation needs (config.Iec104Config, checked): host, port, common_address,
    allowed_clients (IPv4 networks), max_connections, commands, time_tags ("utc" or
    "local"), queue_size, test_after_s (t3), answer_within_s (t1), start_within_s."""

    host: str = "127.0.0.1"
    port: int = 2404
    common_address: int = 1
    allowed_clients: tuple[ipaddress.IPv4Network, ...] = (ipaddress.IPv4Network("127.0.0.1"),)
    max_connections: int = 2
    commands: bool = False
    time_tags: str = "utc"
    queue_size: int = 10_000
    test_after_s: int = 3
    answer_within_s: int = 15
    start_within_s: float = 5.0

    @classmethod
    def from_config(cls, cfg: Iec104Config) -> Iec104Settings:
        """From [iec104] (config.Iec104Config, whose construction checked every value)."""
        nets = tuple(ipaddress.IPv4Network(a, strict=False) for a in cfg.allowed_clients)
        return cls(
            cfg.host,
            cfg.port,
            cfg.common_address,
            nets,
            cfg.max_connections,
            cfg.commands,
            cfg.time_tags,
            cfg.queue_size,
            cfg.test_after_s,
            cfg.answer_within_s,
            cfg.start_within_s,
        )

    def allows(self, ip: str) -> bool:
        """Whether a client at `ip` ("a.b.c.d", or "a.b.c.d:port") may connect."""
        try:
            addr = ipaddress.IPv4Address(ip.rsplit(":", 1)[0] if ip.count(":") == 1 else ip)
        except ValueError:
            return False
        return any(addr in net for net in self.allowed_clients)

    def stamp(self, wall_t: float) -> dt.datetime:
        """A time tag (CP56Time2a: c104 writes the datetime's fields) of a Unix time."""
        if self.time_tags == "local":
            return dt.datetime.fromtimestamp(wall_t)
        return dt.datetime.fromtimestamp(wall_t, dt.UTC)

    def unix(self, fields: dt.datetime) -> float:
        """A master's time (CP56Time2a fields, no zone) as a Unix time, read as time_tags."""
        if fields.tzinfo is not None:
            return fields.timestamp()
        if self.time_tags == "local":
            return fields.timestamp()
        return fields.replace(tzinfo=dt.UTC).timestamp()
