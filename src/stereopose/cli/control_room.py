"""`stereopose control-room [run] CONFIG.toml`: many sites' events in one store, over the central
broker; `control-room sites add|list|remove [NAME...] --config CONFIG.toml`: the sites it takes
(each with its own broker login); `control-room broker-config --config CONFIG.toml --out DIR`:
the central broker's password file and ACL for them."""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import TYPE_CHECKING

from stereopose.cli.common import out
from stereopose.errors import ConfigError

if TYPE_CHECKING:
    from stereopose.controlroom.enrolment import Enrolment
    from stereopose.controlroom.service import ControlPlan
    from stereopose.controlroom.store import ControlStore

USAGE = (
    "control-room [run] CONFIG.toml | control-room sites add|list|remove [NAME...] --config "
    "CONFIG.toml | control-room broker-config --config CONFIG.toml --out DIR"
)


def _control_room(args: argparse.Namespace) -> int:
    if args.cr_action == "sites":
        return _sites(args, [args.sites_action, *args.names])
    if args.cr_action == "broker-config":
        return _broker_config(args)
    if len(args.config) != 1:
        raise ConfigError(f"control-room: one configuration file, or: {USAGE}")
    return _serve(Path(args.config[0]))


def _serve(config: Path) -> int:
    from stereopose.controlroom.service import run_control_room

    def ready(url: str, plan: ControlPlan) -> None:
        from stereopose.controlroom.store import shown_database

        out.print(
            f"control room: {url}/api/sites, health {url}/api/health, metrics "
            f"{url}/metrics; store {shown_database(plan.database)}; broker {plan.mqtt.host}:"
            f"{plan.mqtt.port}; stop with Ctrl-C or SIGTERM",
            highlight=False,
            soft_wrap=True,
        )

    run_control_room(config, on_ready=ready)
    out.print("control room stopped", highlight=False)
    return 0


def _enrolment(args: argparse.Namespace) -> tuple[ControlPlan, ControlStore, Enrolment]:
    """(the control room's plan, its store, the store's enrolment) of --config."""
    from stereopose.controlroom.enrolment import Enrolment
    from stereopose.controlroom.service import plan_control_room
    from stereopose.controlroom.store import ControlStore

    if args.config is None:
        raise ConfigError(f"--config: the control room's configuration is needed: {USAGE}")
    plan = plan_control_room(args.config)
    store = ControlStore(plan.database)
    return plan, store, Enrolment(store)


def _sites(args: argparse.Namespace, rest: list[str]) -> int:
    from stereopose.controlroom.enrolment import check_name

    if not rest or rest[0] not in ("add", "list", "remove"):
        raise ConfigError(f"control-room sites: add, list or remove: {USAGE}")
    action, names = rest[0], rest[1:]
    if (action == "list") != (not names):
        raise ConfigError(
            "control-room sites list takes no NAME"
            if action == "list"
            else f"control-room sites {action}: give the site's NAME"
        )
    names = [check_name(n) for n in names]
    plan, store, enrolment = _enrolment(args)
    try:
        if action == "list":
            return _list(enrolment)
        if action == "remove":
            unknown = [n for n in names if n not in enrolment.names()]
            if unknown:
                raise ConfigError(f"not enrolled: {', '.join(unknown)}")
            for name in names:
                enrolment.remove(name)
                out.print(
                    f"site {name} removed: its messages are refused from now on; what it sent "
                    "stays. Write the broker's files again (control-room broker-config) to end "
                    "its login.",
                    highlight=False,
                    soft_wrap=True,
                )
            return 0
        if args.bridge is not None and len(names) != 1:
            raise ConfigError("--bridge: one site at a time")
        for name in names:
            _add(plan, enrolment, name, args.bridge)
        return 0
    finally:
        store.close()


def _list(enrolment: Enrolment) -> int:
    rows = enrolment.list()
    if not rows:
        out.print("no site enrolled", highlight=False)
    for r in rows:
        added = time.strftime("%Y-%m-%d %H:%M", time.localtime(r.added)) if r.added else "upgrade"
        login = "broker login" if r.has_login else "no broker login (sites add gives one)"
        out.print(f"{r.site}\tenrolled {added}\t{login}", highlight=False, markup=False)
    return 0


def _add(plan: ControlPlan, enrolment: Enrolment, name: str, bridge: Path | None) -> int:
    from stereopose.controlroom.enrolment import broker_hash, login_of, new_password

    cap = plan.config.control_room.max_sites
    enrolled = enrolment.names()
    if name not in enrolled and len(enrolled) >= cap:
        raise ConfigError(
            f"{plan.config_path}: control_room.max_sites = {cap}: {cap} sites are enrolled "
            "already; remove one or raise the bound"
        )
    password = new_password()
    new = enrolment.add(name, broker_hash(password), time.time())
    lines = [
        f"remote_username {login_of(name)}",
        f"remote_password {password}",
    ]
    if bridge is not None:
        _write_bridge(bridge, plan, name, password)
    out.print(
        f"site {name} {'enrolled' if new else 'given a new broker login (the old one ends)'}; "
        "its messages are stored from now on. Write the central broker's files again "
        f"(stereopose control-room broker-config --config {plan.config_path} --out DIR) and "
        "reload it. The site's bridge logs in with (shown once, not kept here):",
        highlight=False,
        soft_wrap=True,
    )
    for line in lines:
        out.print(f"  {line}", highlight=False, markup=False)
    if bridge is not None:
        out.print(f"wrote {bridge} (the site's bridge configuration)", highlight=False)
    return 0


def _write_bridge(path: Path, plan: ControlPlan, name: str, password: str) -> None:
    """The shipped site-bridge.conf for `name`, with its login and the central broker's
    address, readable by its owner only."""
    from importlib import resources

    from stereopose.io.writing import write_private

    text = (resources.files("stereopose") / "data" / "site-bridge.conf").read_text("utf-8")
    text = (
        f"# Site {name}'s Mosquitto bridged to the control room's central broker, written by\n"
        "# `stereopose control-room sites add`. Put it in /etc/mosquitto/conf.d/ on the site's\n"
        "# box (readable by mosquitto only: it holds the site's password).\n"
        + text.split("\n\n", 1)[1]
    )
    from stereopose.io.sinks.mqtt_settings import topic_part

    prefix = plan.mqtt.topic_prefix
    text = text.replace("stereopose/SITE/", f"{prefix}/{topic_part(name)}/")
    text = text.replace("stereopose-bridge-SITE", f"stereopose-bridge-{name}")
    text = text.replace("site-SITE", f"site-{name}")
    text = text.replace("central.example.org:8883", f"{plan.mqtt.host}:{plan.mqtt.port}")
    text = text.replace("remote_password CHANGE-ME", f"remote_password {password}")
    write_private(path, text.encode("utf-8"))


def _broker_config(args: argparse.Namespace) -> int:
    from stereopose.controlroom.broker_config import write_broker_config
    from stereopose.controlroom.enrolment import broker_hash

    if args.out is None:
        raise ConfigError(f"control-room broker-config: --out DIR is needed: {USAGE}")
    plan, store, enrolment = _enrolment(args)
    try:
        m = plan.mqtt
        if not m.username or not m.password:
            raise ConfigError(
                f"{plan.config_path}: mqtt.username and mqtt.password(_file): the central "
                "broker's files need the control room's own login"
            )
        logins = enrolment.logins()
        without = [r.site for r in enrolment.list() if not r.has_login]
        passwd, acl = write_broker_config(
            args.out, m.topic_prefix, (m.username, broker_hash(m.password)), logins
        )
    finally:
        store.close()
    out.print(f"wrote {passwd} and {acl}: the control room and {len(logins)} site login(s)")
    if without:
        out.print(
            f"enrolled without a broker login (control-room sites add NAME gives one): "
            f"{', '.join(without)}",
            highlight=False,
            markup=False,
        )
    out.print(
        "Install them as the central broker's password_file and acl_file (readable by its "
        "user only), then reload it (systemctl reload mosquitto).",
        highlight=False,
    )
    return 0
