"""`stereopose control-room` as a real process against a real mosquitto: sites (each a real
event log published by its outbox, and one served demo) stored centrally, each (site, id)
once, across a SIGKILL of the control room, a broker restart and a site away; its API behind
the console's login; a site stopped shown offline; bad configurations exit 2."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import httpx
import pytest

from brokers import Broker, free_port
from stereopose.controlroom.store import ControlStore
from stereopose.io.sinks.eventwriter import SqliteSink
from stereopose.io.sinks.mqtt import MqttSettings
from stereopose.site.eventlog import EventLog
from stereopose.site.outbox import LogOutbox, OutboxPace
from stereopose.types import Event
from waiting import wait_until

ENV = dict(os.environ, PYTHONUNBUFFERED="1", PYTHONDONTWRITEBYTECODE="1")


class Site:
    """A site's event log (a real SqliteSink) and its outbox to the broker (logged in with
    `login`: username and password, where given)."""

    def __init__(self, folder: Path, name: str, port: int, **login: str) -> None:
        self.name, self.k = name, 0
        self.sink = SqliteSink(folder / f"{name}.sqlite", "site.toml", "test", wall_start=1.8e9)
        self.log = EventLog(folder / f"{name}.sqlite")
        self.box = LogOutbox(
            MqttSettings(
                host="127.0.0.1",
                port=port,
                site=name,
                reconnect_min_s=0.05,
                reconnect_max_s=0.2,
                **login,
            ),
            self.log,
            pace=OutboxPace(resend_s=1.0),
        )

    def write(self, n: int) -> None:
        evs = []
        for _ in range(n):
            self.k += 1
            evs.append(
                Event(
                    t=self.k / 25,
                    frame=self.k,
                    person=self.k % 2,
                    zone="bus",
                    kind="energized",
                    type="enter",
                    onset_t=self.k / 25,
                )
            )
        self.sink.write_events(evs)

    def ids(self) -> list[int]:
        return [e["id"] for e in self.log.after(0, limit=100_000)]

    def close(self) -> None:
        self.box.close()
        self.sink.close()


def _config(folder: Path, broker_port: int, http_port: int, extra: str = "") -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "control.toml"
    path.write_text(
        f'output = "data"\n\n[serve]\nport = {http_port}\n\n[mqtt]\n'
        f'host = "127.0.0.1"\nport = {broker_port}\n{extra}'
    )
    return path


def _add_user(config: Path) -> None:
    add = subprocess.run(
        [
            sys.executable,
            "-m",
            "stereopose.cli",
            "users",
            "add",
            "vera",
            "--role",
            "viewer",
            "--config",
            str(config),
        ],
        input="vera-password\n",
        text=True,
        capture_output=True,
        env=ENV,
        timeout=60,
    )
    assert add.returncode == 0, add.stderr


def _start(config: Path, log: Path) -> subprocess.Popen:
    with open(log, "ab") as f:
        cmd = [sys.executable, "-m", "stereopose.cli", "control-room", str(config)]
        return subprocess.Popen(cmd, stdout=f, stderr=subprocess.STDOUT, env=ENV)


def _client(http_port: int) -> httpx.Client:
    c = httpx.Client(base_url=f"http://127.0.0.1:{http_port}", timeout=30)

    def up() -> bool:
        try:
            return c.get("/api/health").status_code == 200
        except httpx.HTTPError:
            return False

    wait_until(up, "the control room's API", timeout_s=60, poll_s=0.2)
    r = c.post("/api/login", json={"username": "vera", "password": "vera-password"})
    assert r.status_code == 200, r.text
    c.headers["Authorization"] = f"Bearer {r.json()['token']}"
    return c


def _central(c: httpx.Client, site: str) -> list[int]:
    ids, after = [], 0
    while True:  # every page, in id order
        page = c.get("/api/events", params={"site": site, "after_id": after, "limit": 7}).json()
        got = [e["id"] for e in page["events"]]
        assert all(e["site"] == site for e in page["events"])
        if not got:
            return ids
        ids += got
        after = got[-1]


@pytest.mark.slow
@pytest.mark.parametrize("database", ["sqlite", "postgresql"])
def test_sites_stored_once_across_a_kill_a_broker_restart_and_a_site_away(
    tmp_path, request, database
):
    broker = Broker(tmp_path / "broker").start()
    http_port = free_port()
    extra, store_at = "", tmp_path / "room" / "data" / "control.sqlite"
    if database == "postgresql":  # its password from a file of the owner's only
        from postgres import PASSWORD

        pg = request.getfixturevalue("postgres")
        store_at = pg.database(f"t{os.getpid()}{free_port()}")
        (tmp_path / "room").mkdir()
        (tmp_path / "room" / "db.secret").write_text(PASSWORD + "\n")
        (tmp_path / "room" / "db.secret").chmod(0o600)
        without = store_at.replace(f":{PASSWORD}@", "@")
        extra = f'[control_room]\ndatabase = "{without}"\ndatabase_password_file = "db.secret"\n'
    config = _config(tmp_path / "room", broker.port, http_port, extra)
    _add_user(config)
    _enrol(config, "north", "south/yard")
    log = tmp_path / "room.log"
    a, b = Site(tmp_path, "north", broker.port), Site(tmp_path, "south/yard", broker.port)
    a.write(5)  # before the control room exists: it asks for them (a gap after its mark 0)
    proc = _start(config, log)
    try:
        c = _client(http_port)
        assert httpx.get(f"http://127.0.0.1:{http_port}/api/sites").status_code == 401
        a.write(10)
        b.write(8)
        wait_until(lambda: _central(c, "north") == a.ids(), "north's events", timeout_s=30)
        wait_until(lambda: _central(c, "south/yard") == b.ids(), "south's events", timeout_s=30)
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=10)
        a.write(20)  # while the control room is dead
        broker.restart()
        b.write(4)
        proc = _start(config, log)
        c = _client(http_port)
        a.write(3)
        wait_until(lambda: _central(c, "north") == a.ids(), "north after the kill", timeout_s=30)
        wait_until(
            lambda: _central(c, "south/yard") == b.ids(), "south after the restart", timeout_s=30
        )
        sites = {s["site"]: s for s in c.get("/api/sites").json()["sites"]}
        assert set(sites) == {"north", "south/yard"}
        assert sites["north"]["events"] == len(a.ids()) == 38
        assert sites["north"]["mark"] == a.ids()[-1] and sites["north"]["state"] == "live"
        health = c.get("/api/health").json()
        assert health["status"] == "ok" and health["broker"] is True
        metrics = c.get("/metrics").text
        assert 'stereopose_controlroom_sites{state="live"} 2.0' in metrics
        assert "stereopose_controlroom_duplicates_dropped_total" in metrics
    finally:
        proc.send_signal(signal.SIGTERM)
        rc = proc.wait(timeout=30)
        a.close()
        b.close()
        broker.stop()
    assert rc == 0, log.read_text()
    if database == "postgresql":
        assert "postgresql://stereopose:***@127.0.0.1" in log.read_text()
        assert PASSWORD not in log.read_text()
    store = ControlStore(store_at)
    try:  # each (site, id) once, exactly the sites' logs
        assert [e["id"] for e in store.events("north", 0, 1000)] == a.ids()
        assert [e["id"] for e in store.events("south/yard", 0, 1000)] == b.ids()
    finally:
        store.close()


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        ('[control_room]\ndatabase = "postgresql:fleet"\n', "a PostgreSQL URL reads"),
        (
            '[control_room]\ndatabase = "postgresql://u:p@db/x"\ndatabase_password_file = "no"\n',
            "give one of them",
        ),
        ("[control_room]\noffline_after_s = -1\n", "control_room.offline_after_s"),
        ("[control_room]\nhost = 1\n", "unknown key"),
    ],
)
def test_a_bad_configuration_is_exit_2_naming_the_key(tmp_path, extra, message):
    config = _config(tmp_path, free_port(), free_port(), extra)
    r = subprocess.run(
        [sys.executable, "-m", "stereopose.cli", "control-room", str(config)],
        capture_output=True,
        text=True,
        env=ENV,
        timeout=60,
    )
    assert r.returncode == 2 and message in r.stderr and "Traceback" not in r.stderr, r.stderr


def test_no_broker_configured_is_exit_2(tmp_path):
    config = tmp_path / "control.toml"
    config.write_text('output = "data"\n')
    r = subprocess.run(
        [sys.executable, "-m", "stereopose.cli", "control-room", str(config)],
        capture_output=True,
        text=True,
        env=ENV,
        timeout=60,
    )
    assert r.returncode == 2 and "mqtt.host" in r.stderr, r.stderr


@pytest.mark.realdata
@pytest.mark.slow
def test_a_served_site_reaches_the_control_room_and_shows_offline_when_stopped(tmp_path):
    import sqlite3

    from stereopose.pipeline.demo import write_serve_demo_config

    broker = Broker(tmp_path / "broker").start()
    http_port = free_port()
    room_config = _config(tmp_path / "room", broker.port, http_port)
    _add_user(room_config)
    _enrol(room_config, "demo")
    site_config = write_serve_demo_config(
        tmp_path / "demo", tmp_path / "data", free_port(), imgsz=320
    )
    site_config.write_text(
        site_config.read_text().replace(
            "[serve]\n",
            f'[mqtt]\nhost = "127.0.0.1"\nport = {broker.port}\nsite = "demo"\n\n[serve]\n',
            1,
        )
    )
    db = tmp_path / "data" / "events.sqlite"

    def site_ids() -> list[int]:
        if not db.exists():
            return []
        con = sqlite3.connect(f"file:{db}?mode=ro", uri=True, timeout=5)
        try:
            return [i for (i,) in con.execute("SELECT id FROM events ORDER BY id")]
        except sqlite3.OperationalError:
            return []
        finally:
            con.close()

    room = _start(room_config, tmp_path / "room.log")
    with open(tmp_path / "serve.log", "ab") as f:
        serve = subprocess.Popen(
            [sys.executable, "-m", "stereopose.cli", "serve", str(site_config)],
            stdout=f,
            stderr=subprocess.STDOUT,
            env=ENV,
        )
    try:
        c = _client(http_port)
        wait_until(lambda: len(site_ids()) >= 3, "the site's events", timeout_s=120, poll_s=0.5)
        wait_until(
            lambda: set(site_ids()[:3]) <= set(_central(c, "demo")),
            "them in the control room",
            timeout_s=30,
        )
        site = {s["site"]: s for s in c.get("/api/sites").json()["sites"]}["demo"]
        assert site["state"] in ("live", "degraded")  # degraded: its own health says so
        serve.send_signal(signal.SIGTERM)
        assert serve.wait(timeout=60) == 0, (tmp_path / "serve.log").read_text()

        def state() -> str:
            return {s["site"]: s for s in c.get("/api/sites").json()["sites"]}["demo"]["state"]

        wait_until(lambda: state() == "offline", "the site offline", timeout_s=30)
        # what the site stored, to its last event at the stop, is all there, each once
        wait_until(
            lambda: _central(c, "demo") == site_ids(), "every event of the site", timeout_s=30
        )
    finally:
        if serve.poll() is None:
            serve.kill()
        room.send_signal(signal.SIGTERM)
        room.wait(timeout=30)
        broker.stop()


def _login(http_port: int, user: str, password: str) -> httpx.Client:
    c = httpx.Client(base_url=f"http://127.0.0.1:{http_port}", timeout=30)
    r = c.post("/api/login", json={"username": user, "password": password})
    assert r.status_code == 200, r.text
    c.headers["Authorization"] = f"Bearer {r.json()['token']}"
    return c


def _add(config: Path, name: str, role: str, *more: str) -> None:
    add = subprocess.run(
        [
            sys.executable,
            "-m",
            "stereopose.cli",
            "users",
            "add",
            name,
            "--role",
            role,
            *more,
            "--config",
            str(config),
        ],
        input=f"{name}-password\n",
        text=True,
        capture_output=True,
        env=ENV,
        timeout=60,
    )
    assert add.returncode == 0, add.stderr


@pytest.mark.slow
def test_incidents_acks_users_limited_to_sites_and_the_console_page(tmp_path):
    from test_incidents import Site as IncidentSite

    broker = Broker(tmp_path / "broker").start()
    http_port = free_port()
    config = _config(
        tmp_path / "room",
        broker.port,
        http_port,
        '[control_room]\nname = "utility-cr"\ncommand_resend_s = 0.5\n',
    )
    _add_user(config)  # vera, a viewer of every site
    _add(config, "olga", "operator", "--sites", "north")
    _enrol(config, "north", "south")
    listed = subprocess.run(
        [sys.executable, "-m", "stereopose.cli", "users", "list", "--config", str(config)],
        capture_output=True,
        text=True,
        env=ENV,
        timeout=60,
    )
    assert listed.stdout.split("\n")[0].split() == ["olga", "operator", "north"], listed.stdout
    plan = {
        "zones": [
            {"name": "busbar", "kind": "energized", "polygon": [[0, 0], [2, 0], [2, 1], [0, 1]]}
        ],
        "console_url": "https://north.example.org:8787/",
    }
    north = IncidentSite(tmp_path, broker.port, "north", plan=plan)
    south = IncidentSite(tmp_path, broker.port, "south")
    proc = _start(config, tmp_path / "room.log")
    try:
        vera = _client(http_port)
        olga = _login(http_port, "olga", "olga-password")
        n_inc, s_inc = north.enter(), south.enter()

        def central(c: httpx.Client, site: str) -> dict:
            found = c.get("/api/incidents", params={"site": site}).json()["incidents"]
            return {i["id"]: i for i in found if i["source"] == "site"}

        wait_until(
            lambda: n_inc in central(vera, "north") and s_inc in central(vera, "south"),
            "both sites' incidents",
            timeout_s=30,
        )
        wait_until(
            lambda: (
                {s["site"] for s in vera.get("/api/sites").json()["sites"]} == {"north", "south"}
            ),
            "both sites listed",
        )
        assert {s["site"] for s in olga.get("/api/sites").json()["sites"]} == {"north"}
        north_row = next(s for s in vera.get("/api/sites").json()["sites"] if s["site"] == "north")
        assert north_row["open_incidents"] == 1 and north_row["open_by_priority"] == {"1": 1}
        assert olga.get("/api/events", params={"site": "south"}).json()["events"] == []
        assert central(olga, "south") == {}
        assert olga.get("/api/sites/south/plan").status_code == 404
        # a viewer may not acknowledge; an operator not another's site
        assert vera.post(f"/api/sites/north/incidents/{n_inc}/ack").status_code == 403
        assert olga.post(f"/api/sites/south/incidents/{s_inc}/ack").status_code == 404
        assert olga.post("/api/sites/north/incidents/99999/ack").status_code == 404
        r = olga.post(f"/api/sites/north/incidents/{n_inc}/ack")
        assert r.status_code == 202 and r.json()["command"] is not None, r.text
        wait_until(
            lambda: north.record(n_inc).acked_by == "olga via utility-cr",
            "the acknowledgement at the site",
            timeout_s=30,
        )
        north.run()
        wait_until(
            lambda: central(vera, "north")[n_inc].get("acked_by") == "olga via utility-cr",
            "the acknowledgement back",
            timeout_s=30,
        )
        again = olga.post(f"/api/sites/north/incidents/{n_inc}/ack")
        assert again.status_code == 200 and again.json()["command"] is None
        # the site's page: its plan, its people followed while looked at, its console's link
        page = olga.get("/api/sites/north/plan").json()
        wait_until(
            lambda: olga.get("/api/sites/north/plan").json()["plan"] == plan, "the site's plan"
        )
        assert page["site"] == "north"
        assert olga.get("/api/sites/north/plan").json()["console_url"] == plan["console_url"]
        # the console's page and its files, with the site console's headers
        root = httpx.get(f"http://127.0.0.1:{http_port}/")
        assert root.status_code == 200 and "control room" in root.text
        assert "default-src 'self'" in root.headers["content-security-policy"]
        for path in ("/room/room.js", "/room/room.css", "/console/console.css", "/console/api.js"):
            assert httpx.get(f"http://127.0.0.1:{http_port}{path}").status_code == 200, path
        assert httpx.get(f"http://127.0.0.1:{http_port}/room/%2e%2e/page.py").status_code == 404
        metrics = vera.get("/metrics").text
        assert "stereopose_controlroom_commands_done_total 1.0" in metrics
    finally:
        proc.send_signal(signal.SIGTERM)
        rc = proc.wait(timeout=30)
        north.close()
        south.close()
        broker.stop()
    assert rc == 0, (tmp_path / "room.log").read_text()


def _enrol(config: Path, *sites: str) -> None:
    """`stereopose control-room sites add` of each site: the only names the room stores."""
    add = subprocess.run(
        [
            sys.executable,
            "-m",
            "stereopose.cli",
            "control-room",
            "sites",
            "add",
            *sites,
            "--config",
            str(config),
        ],
        capture_output=True,
        text=True,
        env=ENV,
    )
    assert add.returncode == 0, add.stdout + add.stderr
