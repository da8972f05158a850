"""Helpers of the console tests: the real demo's rig and site, an event log written by the
real SQLite sink, and a real server with the console's parts over an output folder."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import httpx
from argon2 import PasswordHasher

from stereopose.io.sinks.eventwriter import SqliteSink
from stereopose.pipeline.demo import write_serve_demo_config
from stereopose.site.eventlog import EventLog
from stereopose.site.health.state import ServiceState
from stereopose.site.http.app import create_app
from stereopose.site.http.web import Console
from stereopose.site.live import LiveHub
from stereopose.site.plan import plan_serve
from stereopose.types import Event
from stereopose.web.server import Server, ServeSettings
from stereopose.web.users import UserStore

PASSWORDS = {"vera": "viewer-pass-1", "otto": "operator-pass-1", "ada": "admin-pass-1"}
ROLES = {"vera": "viewer", "otto": "operator", "ada": "admin"}
WALL_START = 1_780_000_000.0  # 2026-05-28T20:26:40Z


def fast_hasher() -> PasswordHasher:
    """argon2id with a small memory cost: the same code path, quicker on a loaded machine."""
    return PasswordHasher(time_cost=1, memory_cost=8 * 1024, parallelism=1)


def demo_plan(folder: Path):
    """The checked plan of the real demo served (its rig and site)."""
    return plan_serve(write_serve_demo_config(folder / "demo", folder / "data", 0, imgsz=320))


def zone_event(
    frame: int,
    type_: str = "enter",
    person: int = 7,
    zone: str = "overhead_busbar",
    kind: str = "energized",
) -> Event:
    return Event(
        t=frame / 30.0,
        frame=frame,
        person=person,
        zone=zone,
        kind=kind,
        type=type_,
        onset_t=frame / 30.0,
        position=(0.1, -0.2),
    )


@dataclass
class Served:
    server: Server
    console: Console
    out: Path
    db: SqliteSink | None
    state: ServiceState

    @property
    def url(self) -> str:
        return self.server.url

    def client(self, user: str | None = None, **kw) -> httpx.Client:
        """An httpx client, logged in as `user` (its cookies) when given."""
        c = httpx.Client(base_url=self.url, timeout=30, **kw)
        if user is not None:
            r = c.post("/api/login", json={"username": user, "password": PASSWORDS[user]})
            assert r.status_code == 200, r.text
            c.headers["X-CSRF-Token"] = r.json()["csrf"]
        return c


@contextlib.contextmanager
def console_server(
    out: Path,
    plan=None,
    *,
    users: bool = True,
    events: bool = True,
    settings: ServeSettings | None = None,
    app_kw: dict | None = None,
    **server_kw,
) -> Iterator[Served]:
    """A real server over `out` with the console; users: the three of ROLES added; events:
    an event log opened by the real sink (its wall_start WALL_START); plan: the demo's plan
    (its rig and site feed a live hub; None: no hub); app_kw: more of create_app's keywords."""
    out.mkdir(parents=True, exist_ok=True)
    store = UserStore.in_folder(out, hasher=fast_hasher())
    if users:
        for name, role in ROLES.items():
            store.add(name, PASSWORDS[name], role)
    db = (
        SqliteSink(out / "events.sqlite", "site", "test", wall_start=WALL_START) if events else None
    )
    state = ServiceState(plan.rig.names if plan is not None else ())
    hub = None
    if plan is not None:
        hub = LiveHub(plan.rig, plan.site, state, EventLog(out / "events.sqlite", out / "clips"))
    console = Console.in_folder(out, hub, users=store)
    server = Server(
        create_app(state, console=console, **(app_kw or {})),
        settings or ServeSettings(port=0),
        users=store.count,
        **server_kw,
    )
    server.start()
    if hub is not None:
        hub.start()
    try:
        yield Served(server, console, out, db, state)
    finally:
        console.close()
        server.stop()
        if db is not None:
            db.close()
