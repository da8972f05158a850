"""`stereopose control-room CONFIG.toml`: the ingest, the store and the HTTP API of one control
room, until SIGINT or SIGTERM.

The configuration reads like a site's: `output` (the control room's folder: its store
`control.sqlite`, its `users.json`), `[serve] host port certificate key allowed_hosts`,
`[mqtt] host port username password(_file) tls ca_file topic_prefix` (the central broker),
and `[control_room]` (`database`, `offline_after_s`, `clock_tolerance_s`, `name`,
`command_resend_s`, `sites`, `max_sites`, `max_event_bytes`, `max_heartbeat_bytes`,
`ids_ahead`). Everything is checked before anything
starts; a bad value is exit 2 naming the file and the key.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from stereopose.config import Config, load_config
from stereopose.controlroom.ingest import Ingest
from stereopose.controlroom.store import ControlStore
from stereopose.errors import ConfigError

if TYPE_CHECKING:
    from stereopose.io.sinks.mqtt_settings import MqttSettings
    from stereopose.web.server import ServeSettings

__all__ = ["ControlRoom", "plan_control_room", "run_control_room"]

logger = logging.getLogger(__name__)

STORE = "control.sqlite"


@dataclass(frozen=True)
class ControlPlan:
    config_path: Path
    config: Config
    out_dir: Path
    database: Path | str  # an SQLite file, or a postgresql:// URL
    mqtt: MqttSettings
    http: ServeSettings


def plan_control_room(config_path: str | Path) -> ControlPlan:
    from stereopose.config_refs import (
        mqtt_settings,
        read_secret,
        resolve,
        section_settings,
        tls_files,
    )
    from stereopose.web.server import ServeSettings

    path = Path(config_path)
    if not path.is_file():
        raise ConfigError(f"{path}: configuration file not found")
    cfg = load_config(path)
    base = path.resolve().parent
    if not cfg.mqtt.host:
        raise ConfigError(f"{path}: mqtt.host: the control room needs the central broker")
    mqtt = mqtt_settings(path, base, cfg)
    assert mqtt is not None  # its host is given
    db = cfg.control_room.database
    out_dir = resolve(base, cfg.output)
    database: Path | str
    if db.startswith(("postgresql:", "postgres:")):
        if not db.startswith(("postgresql://", "postgres://")):
            raise ConfigError(
                f"{path}: control_room.database: a PostgreSQL URL reads "
                "postgresql://USER:PASSWORD@HOST:PORT/DATABASE"
            )
        try:
            import psycopg  # noqa: F401
        except ImportError:
            raise ConfigError(
                f"{path}: control_room.database: PostgreSQL needs psycopg 3 "
                "(pip install 'stereopose[postgresql]')"
            ) from None
        database = db
        secret = cfg.control_room.database_password_file
        if secret:
            from urllib.parse import quote, urlsplit, urlunsplit

            parts = urlsplit(db)
            if parts.password is not None:
                raise ConfigError(
                    f"{path}: control_room.database has a password and "
                    "database_password_file gives one: give one of them"
                )
            word = quote(
                read_secret(resolve(base, secret), "control_room.database_password_file", path),
                safe="",
            )
            user = quote(parts.username or "", safe="")
            host = parts.netloc.rpartition("@")[2]
            database = urlunsplit(parts._replace(netloc=f"{user}:{word}@{host}"))
    else:
        if cfg.control_room.shared_group:
            raise ConfigError(
                f"{path}: control_room.shared_group: several workers share one "
                "PostgreSQL store; give control_room.database = "
                '"postgresql://..."'
            )
        database = resolve(out_dir, db.removeprefix("sqlite:///")) if db else out_dir / STORE
    certificate, key = tls_files(path, base, cfg)
    http = section_settings(
        path,
        ServeSettings,
        host=cfg.serve.host,
        port=cfg.serve.port,
        certificate=certificate,
        key=key,
        trusted_proxies=cfg.serve.trusted_proxies,
    )
    return ControlPlan(path, cfg, out_dir, database, mqtt, http)


class ControlRoom:
    """The running parts: store, ingest, console (the login), and the HTTP server."""

    def __init__(self, plan: ControlPlan) -> None:
        from stereopose.controlroom.app import create_control_app
        from stereopose.io.writing import make_folder
        from stereopose.web.auth import Logins, Sessions
        from stereopose.web.hosts import allowed_hosts
        from stereopose.web.server import Server
        from stereopose.web.users import UserStore

        self.plan = plan
        make_folder(plan.out_dir)
        self.store = ControlStore(plan.database)
        users = UserStore.in_folder(plan.out_dir)
        self.console = Logins(users, Sessions(users))
        hosts = allowed_hosts(plan.http.host, plan.config.serve.allowed_hosts)
        app = create_control_app(self, allowed_hosts=hosts)
        hint = f"stereopose users add NAME --role admin --config {plan.config_path}"
        self.server = Server(app, plan.http, users=users.count, users_hint=hint)
        self.ingest: Ingest | None = None
        self.server.start()
        self.url = self.server.url
        self.ingest = Ingest(plan.mqtt, self.store, plan.config.control_room)

    def close(self) -> None:
        if self.ingest is not None:
            self.ingest.close()
        self.server.stop()
        self.store.close()


def run_control_room(
    config_path: str | Path,
    stop: threading.Event | None = None,
    on_ready: Callable[[str, ControlPlan], None] | None = None,
) -> None:
    from stereopose.pipeline.private import private_files, tighten
    from stereopose.site.parts import quiet_signals, stop_signals

    plan = plan_control_room(config_path)
    stop = stop or threading.Event()
    with private_files():
        if plan.out_dir.exists():
            tighten(plan.out_dir)
        with stop_signals():
            room = ControlRoom(plan)
            try:
                if on_ready is not None:
                    on_ready(room.url, plan)
                while not stop.wait(0.5):
                    if room.ingest is not None:
                        room.ingest.ensure_running()
            except KeyboardInterrupt:
                pass
            finally:
                with quiet_signals():
                    room.close()
