"""The central broker's password file and ACL, written from the enrolled sites
(`stereopose control-room broker-config`): the control room's login reads every site and writes
only the control topics; each enrolled site's login (`site-<name>`) writes only under
`<prefix>/<name>/` and reads only its own control topics, so a site cannot publish as another.
Mosquitto reads both again on SIGHUP (`systemctl reload mosquitto`)."""

from __future__ import annotations

from pathlib import Path

from stereopose.controlroom.enrolment import login_of
from stereopose.io.sinks.mqtt_settings import topic_part
from stereopose.io.writing import write_private
from stereopose.site.wire import (
    AVAILABLE,
    COMMAND_ACK,
    COMMAND_DONE,
    CONFIRMED,
    EVENTS,
    HEARTBEAT,
    INCIDENTS,
    PEOPLE,
    PLAN,
    REPLAY,
)

__all__ = ["ACL", "PASSWD", "acl_text", "passwd_text", "write_broker_config"]

PASSWD = "passwd"
ACL = "central-acl"
# a site's own topics out (its MQTT sink's live topics and the outbox's), its control topics in
SITE_WRITES = (
    AVAILABLE,
    "events",
    "incidents",
    "zones/#",
    PEOPLE,
    EVENTS,
    HEARTBEAT,
    INCIDENTS,
    COMMAND_DONE,
    PLAN,
)
SITE_READS = (CONFIRMED, REPLAY, COMMAND_ACK)


def acl_text(prefix: str, room_login: str, sites: list[str]) -> str:
    """The ACL: the control room's block, then one block per site."""
    lines = [
        "# The central broker's ACL, written by `stereopose control-room broker-config` from",
        "# the enrolled sites: each site writes only under its own topics and reads only its",
        "# own control topics; the control room reads every site and writes the control topics.",
        "",
        f"user {room_login}",
        f"topic read {prefix}/#",
        *(f"topic write {prefix}/+/{what}" for what in SITE_READS),
    ]
    for site in sites:
        level = topic_part(site)
        lines += ["", f"user {login_of(site)}"]
        lines += [f"topic write {prefix}/{level}/{what}" for what in SITE_WRITES]
        lines += [f"topic read {prefix}/{level}/{what}" for what in SITE_READS]
    return "\n".join(lines) + "\n"


def passwd_text(room_login: str, room_hash: str, logins: list[tuple[str, str]]) -> str:
    """The password file: the control room's login, then each site's (hashes only)."""
    rows = [f"{room_login}:{room_hash}"] + [f"{login_of(s)}:{h}" for s, h in logins]
    return "\n".join(rows) + "\n"


def write_broker_config(
    out_dir: Path, prefix: str, room: tuple[str, str], logins: list[tuple[str, str]]
) -> tuple[Path, Path]:
    """`out_dir`/passwd and `out_dir`/central-acl for the control room's (login, hash) and the
    sites' (site, hash); their paths."""
    out_dir.mkdir(parents=True, exist_ok=True)
    passwd, acl = out_dir / PASSWD, out_dir / ACL
    write_private(passwd, passwd_text(room[0], room[1], logins).encode())
    write_private(acl, acl_text(prefix, room[0], [s for s, _ in logins]).encode())
    return passwd, acl
