"""Two control-room workers sharing the sites' messages (an MQTT shared subscription on a real
mosquitto, which deals them round robin) and one real PostgreSQL store: every event of every
site stored exactly once, every incident with its latest state, an acknowledgement asked at
either worker reaching its site once, both workers' APIs answering for every site; one worker
killed, the other carries on alone. A shared group without PostgreSQL is exit 2."""

from __future__ import annotations

import signal
import subprocess
import sys

import pytest
from test_control_room import (
    ENV,
    _add,
    _add_user,
    _central,
    _client,
    _config,
    _enrol,
    _login,
    _start,
)
from test_incidents import Site

from brokers import Broker, free_port
from stereopose.controlroom.store import ControlStore
from waiting import wait_until

pytestmark = pytest.mark.slow


def test_two_workers_share_the_sites_each_event_stored_once(tmp_path, postgres):
    broker = Broker(tmp_path / "broker").start()
    url = postgres.database("workers")
    extra = f'[control_room]\ndatabase = "{url}"\nshared_group = "room"\ncommand_resend_s = 1\n'
    ports = [free_port(), free_port()]
    configs = [
        _config(tmp_path / f"w{i}", broker.port, port, extra) for i, port in enumerate(ports)
    ]
    for config in configs:  # each worker's users (its folder); one store
        _add_user(config)
        _add(config, "olga", "operator")
    _enrol(configs[0], "north", "south", "east")  # one store: enrolled for both workers
    sites = [Site(tmp_path, broker.port, name) for name in ("north", "south", "east")]
    procs = [_start(config, tmp_path / f"w{i}.log") for i, config in enumerate(configs)]
    store = ControlStore(url)
    try:
        clients = [_client(port) for port in ports]
        incidents = {}
        for _ in range(6):
            for s in sites:
                incidents.setdefault(s.box.settings.site, s.enter())
                s.enter(type_="exit")
                s.enter(zone="feeder", person=3)
        for s in sites:
            name = s.box.settings.site
            ids = [e["id"] for e in s.box.log.after(0, limit=10_000)]
            for c in clients:  # either worker's API answers for every site
                wait_until(
                    lambda c=c, name=name, ids=ids: _central(c, name) == ids,
                    f"{name}'s events once",
                    timeout_s=60,
                )
        figures = [c.get("/api/health").json()["ingest"] for c in clients]
        assert all(f["messages"] > 0 for f in figures), figures  # both took a share
        # an ack asked at the second worker: the site's answer may reach either
        olga = _login(ports[1], "olga", "olga-password")
        inc = incidents["north"]
        assert olga.post(f"/api/sites/north/incidents/{inc}/ack").status_code == 202
        north = sites[0]
        wait_until(
            lambda: north.record(inc).acked_by == "olga via control-room",
            "the ack at the site",
            timeout_s=30,
        )
        north.run()
        wait_until(
            lambda: (store.incident("north", inc) or {}).get("acked_by") == "olga via control-room",
            "the ack in the store",
            timeout_s=30,
        )
        wait_until(lambda: store.pending_commands() == [], "the command answered", timeout_s=30)
        # one worker gone: the other takes every message
        procs[0].send_signal(signal.SIGKILL)
        procs[0].wait(timeout=10)
        for s in sites:
            s.enter(zone="bay", person=5)
        for s in sites:
            name = s.box.settings.site
            ids = [e["id"] for e in s.box.log.after(0, limit=10_000)]
            wait_until(
                lambda name=name, ids=ids: _central(clients[1], name) == ids,
                f"{name} after a worker died",
                timeout_s=60,
            )
    finally:
        for p in procs:
            if p.poll() is None:
                p.send_signal(signal.SIGTERM)
                p.wait(timeout=30)
        for s in sites:
            s.close()
        store.close()
        broker.stop()


def test_a_shared_group_without_postgresql_is_exit_2(tmp_path):
    config = _config(tmp_path, free_port(), free_port(), '[control_room]\nshared_group = "g"\n')
    r = subprocess.run(
        [sys.executable, "-m", "stereopose.cli", "control-room", str(config)],
        capture_output=True,
        text=True,
        env=ENV,
        timeout=60,
    )
    assert r.returncode == 2 and "control_room.shared_group" in r.stderr, r.stderr
