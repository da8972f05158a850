"""The configuration's SCADA sections: iec104, opcua."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, get_args

from stereopose.config.fields import Section, _schema, number
from stereopose.errors import ConfigError


@_schema("iec104")
@dataclass(frozen=True)
class Iec104Config(Section):
    """serve's IEC 60870-5-104 outstation (stereopose.scada.iec104, docs/scada.md); needs the
    `scada` extra. Off unless enabled; `stereopose points CONFIG.toml` prints its points."""

    enabled: bool = False
    # the address it listens on (IPv4); anything but loopback is reachable from the network
    host: str = "127.0.0.1"
    port: int = number(2404, integer=True, ge=1, le=65535)
    common_address: int = number(1, integer=True, ge=1, le=65534)  # the station's ASDU address
    # the masters that may connect: IPv4 addresses or networks ("10.0.0.0/24"); others are
    # refused at connect
    allowed_clients: tuple[str, ...] = ("127.0.0.1",)
    # open connections at most (a master and its redundant twin); more are refused
    max_connections: int = number(2, integer=True, ge=1, le=64)
    # single commands that acknowledge a zone's or a priority's incidents (off: no command
    # point exists, a command is answered unknown)
    commands: bool = False
    # the time tags' clock: "utc", or "local" (the machine's time zone, as dispatch centres on
    # local time expect)
    time_tags: Literal["utc", "local"] = "utc"
    # point changes held at most for the outstation's thread (then counted as dropped)
    queue_size: int = number(10_000, integer=True, ge=1, le=10_000_000)
    # IEC 104's t3: a link silent this long is tested (TESTFR), and t1: a test or an I-frame
    # unanswered this long closes it (a master's t2, its acknowledgement delay, must stay
    # below t1: the standard's 10 s). A socket that does not speak IEC 104 holds a place for
    # their sum at most (the standard's t3 of 20 s let idle sockets hold the places for 35 s)
    test_after_s: int = number(3, integer=True, ge=1, le=255)
    answer_within_s: int = number(15, integer=True, ge=2, le=255)
    # a connection that has not started data transfer (STARTDT) this long after it opened is
    # closed; and when every place is taken, a new master takes the place of the oldest
    # connection not transferring data
    start_within_s: float = number(5.0, gt=0, le=255)

    def _check(self) -> None:
        import ipaddress

        try:
            ipaddress.IPv4Address(self.host)
        except ValueError:
            raise ConfigError(
                f"iec104.host: expected an IPv4 address to listen on, got {self.host!r}"
            ) from None
        if not self.allowed_clients:
            raise ConfigError("iec104.allowed_clients: empty, so no master could connect")
        for i, a in enumerate(self.allowed_clients):
            try:
                ipaddress.IPv4Network(a, strict=False)
            except ValueError:
                raise ConfigError(
                    f"iec104.allowed_clients[{i}]: expected an IPv4 address or "
                    f'network ("10.0.0.0/24"), got {a!r}'
                ) from None


OpcuaPolicy = Literal[
    "Basic256Sha256_SignAndEncrypt",
    "Basic256Sha256_Sign",
    "Aes128Sha256RsaOaep_SignAndEncrypt",
    "Aes128Sha256RsaOaep_Sign",
    "Aes256Sha256RsaPss_SignAndEncrypt",
    "Aes256Sha256RsaPss_Sign",
]


@_schema("opcua")
@dataclass(frozen=True)
class OpcuaConfig(Section):
    """serve's OPC UA server (stereopose.scada.opcua, docs/scada.md): the site, its zones,
    cameras and counts, and each incident as an Alarms and Conditions alarm; needs the `scada`
    extra. Off unless enabled. Clients log in as the console's users (operator or admin to
    acknowledge)."""

    enabled: bool = False
    # the address it listens on; anything but loopback is reachable from the network
    host: str = "127.0.0.1"
    port: int = number(4840, integer=True, ge=1, le=65535)
    path: str = "/stereopose"  # the endpoint: opc.tcp://host:port/path
    site: str = "site"  # this installation's name: the site object's name in the address space
    # the server's application instance certificate (DER or PEM) and its private key (PEM),
    # relative to the config file, both or neither (the key readable by its owner only);
    # neither: a self-signed pair made once in <output>/opcua/, its thumbprint logged
    certificate: str | None = None
    key: str | None = None
    # a folder of the client certificates that may connect (relative to the config file);
    # unset: any client certificate, the user login decides
    trusted_clients: str | None = None
    # the security policies offered, all signed; no unsecured endpoint is ever offered
    security: tuple[OpcuaPolicy, ...] = ("Basic256Sha256_SignAndEncrypt",)
    # clients without a login may browse and subscribe (never acknowledge)
    allow_anonymous: bool = False
    # client connections at most (more are refused at connect)
    max_connections: int = number(16, integer=True, ge=1, le=1000)
    # incident changes held at most for the server's thread (then counted as dropped)
    queue_size: int = number(10_000, integer=True, ge=1, le=10_000_000)

    def _check(self) -> None:
        import ipaddress
        import re

        try:
            ipaddress.ip_address(self.host)
        except ValueError:
            raise ConfigError(
                f"opcua.host: expected an IP address to listen on, got {self.host!r}"
            ) from None
        if not re.fullmatch(r"(/[A-Za-z0-9._~-]+)*/?", self.path) or len(self.path) > 200:
            raise ConfigError(
                f'opcua.path: expected a URL path such as "/stereopose", got {self.path!r}'
            )
        if not self.site or len(self.site) > 64 or not self.site.isprintable():
            raise ConfigError(f"opcua.site: 1 to 64 printable characters, got {self.site!r}")
        if bool(self.certificate) != bool(self.key):
            raise ConfigError("opcua.certificate and opcua.key: give both or neither")
        if not self.security:
            raise ConfigError("opcua.security: empty, so no client could connect")
        for i, name in enumerate(self.security):
            if name not in get_args(OpcuaPolicy):
                raise ConfigError(
                    f"opcua.security[{i}]: expected one of "
                    f"{list(get_args(OpcuaPolicy))}, got {name!r}"
                )
