"""`stereopose serve` on the real demo takes a new site while it runs: an admin's PUT adds a
zone whose events start within seconds, with no restart and the people's ids going on, and the
MQTT output's retained `site` says the new version and zones; a hand edit and SIGHUP remove it
again (its occupants exit, its retained state cleared); the work area switched off and on
over MQTT (its people exit, who did it said, they enter again); a broken file on SIGHUP keeps
the running site and raises a diagnostic incident naming the file."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import httpx
import paho.mqtt.client as paho
import pytest

from brokers import Broker, Subscriber, free_port
from served import log_rows
from stereopose.pipeline.demo import write_serve_demo_config
from waiting import wait_until

pytestmark = [pytest.mark.realdata, pytest.mark.slow]

FLOOR = {
    "name": "whole_floor",
    "kind": "restricted",
    "polygon": [[-6.0, -6.0], [6.0, -6.0], [6.0, 6.0], [-6.0, 6.0]],
    "z": [0.0, 2.5],
}


def _changes(db: Path) -> list[tuple]:
    return log_rows(
        db,
        "SELECT id, type, source, incident FROM events WHERE type IN "
        "('site_changed', 'site_invalid', 'site_valid') ORDER BY id",
    )


def test_a_site_change_is_taken_while_serving(tmp_path: Path) -> None:
    port = free_port()
    config = write_serve_demo_config(tmp_path / "demo", tmp_path / "data", port, imgsz=320)
    broker = Broker(tmp_path / "broker").start()
    mqtt = (
        f'[mqtt]\nhost = "127.0.0.1"\nport = {broker.port}\nsite = "demo"\ncommands = true\n\n'
        "[serve]\n"
    )
    config.write_text(config.read_text().replace("[serve]\n", mqtt, 1))
    sub = Subscriber(broker.port, "stereopose/demo/site", "stereopose/demo/zones/+")
    site = tmp_path / "demo" / "demo_site.toml"
    db = tmp_path / "data" / "events.sqlite"
    add = [sys.executable, "-m", "stereopose.cli", "users", "add", "ada", "--role", "admin"]
    subprocess.run([*add, "--config", str(config)], input=b"ada's passphrase\n", check=True)
    with open(tmp_path / "serve.log", "ab") as f:
        proc = subprocess.Popen(
            [sys.executable, "-m", "stereopose.cli", "serve", str(config)],
            stdout=f,
            stderr=subprocess.STDOUT,
        )
    try:
        base = f"http://127.0.0.1:{port}"

        def up() -> bool:
            try:
                return httpx.get(f"{base}/api/health", timeout=5).status_code < 500
            except httpx.HTTPError:
                return proc.poll() is not None

        wait_until(up, "the service's API", timeout_s=120, poll_s=0.5)
        assert proc.poll() is None, (tmp_path / "serve.log").read_text()[-3000:]
        c = httpx.Client(base_url=base, timeout=30)
        r = c.post("/api/login", json={"username": "ada", "password": "ada's passphrase"})
        c.headers["X-CSRF-Token"] = r.json()["csrf"]
        wait_until(
            lambda: log_rows(db, "SELECT 1 FROM events WHERE person >= 0 LIMIT 1"),
            "the first people's events",
            timeout_s=120,
            poll_s=0.5,
        )
        ids_before = {p for (p,) in log_rows(db, "SELECT DISTINCT person FROM events")}
        got = c.get("/api/site").json()
        wait_until(lambda: sub.on("stereopose/demo/site"), "the retained site", timeout_s=10)
        assert json.loads(sub.on("stereopose/demo/site")[-1])["version"] == got["version"]
        new = {**got["site"], "zones": [*got["site"]["zones"], FLOOR]}
        saved = time.monotonic()
        r = c.put("/api/site", json={"version": got["version"], "site": new})
        assert r.status_code == 200, r.text
        wait_until(
            lambda: log_rows(
                db, "SELECT 1 FROM events WHERE zone = 'whole_floor' AND type = 'enter'"
            ),
            "an entry of the new zone",
            timeout_s=30,
            poll_s=0.1,
        )
        print(f"the new zone's first entry {time.monotonic() - saved:.1f} s after the save")
        [(_, kind, text, incident)] = _changes(db)
        assert kind == "site_changed" and incident is None
        assert text.startswith("ada: version ") and "zones added whole_floor" in text
        assert "whole_floor" in site.read_text() and "# recording looped" in site.read_text()
        version = c.get("/api/site").json()["version"]

        def said(version: str) -> dict | None:
            bodies = [json.loads(b) for b in sub.on("stereopose/demo/site")]
            return next((b for b in bodies if b["version"] == version), None)

        wait_until(lambda: said(version), "the new site over MQTT", timeout_s=10)
        assert "whole_floor" in said(version)["zones"]
        wait_until(lambda: sub.on("stereopose/demo/zones/whole_floor"), "its zone's state")
        # the people's ids go on: the tracks were not started again
        ids_after = {
            p
            for (p,) in log_rows(
                db, "SELECT DISTINCT person FROM events WHERE zone = 'whole_floor'"
            )
        }
        assert ids_after & ids_before

        # a hand edit, then SIGHUP: the zone removed, its occupants exit
        site.write_text(site.read_text().replace('name = "whole_floor"', 'name = "floor_b"'))
        proc.send_signal(signal.SIGHUP)
        wait_until(lambda: len(_changes(db)) == 2, "the hand edit taken", timeout_s=30)
        text = _changes(db)[1][2]
        assert "SIGHUP" in text and "added floor_b" in text and "removed whole_floor" in text
        exits = log_rows(
            db, "SELECT source FROM events WHERE zone = 'whole_floor' AND type = 'exit' "
        )
        assert ("site changed: zone removed",) in exits
        wait_until(
            lambda: "" in sub.on("stereopose/demo/zones/whole_floor"),
            "the removed zone's retained state cleared",
            timeout_s=10,
        )

        # the work area switched off over MQTT, then on again: its people exit, who did it is
        # said, and they enter again
        def zone_rows() -> list[tuple]:
            return log_rows(
                db,
                "SELECT type, source FROM events WHERE zone = 'work_area' AND "
                "type IN ('zone_disabled', 'zone_enabled', 'exit') ORDER BY id",
            )

        control = paho.Client(paho.CallbackAPIVersion.VERSION2, protocol=paho.MQTTv311)
        control.connect("127.0.0.1", broker.port)  # a control desk's client
        control.loop_start()
        topic = "stereopose/demo/zones/work_area/enabled"
        control.publish(topic, '{"enabled": false, "by": "desk 1"}', qos=1).wait_for_publish(5)
        wait_until(
            lambda: ("zone_disabled", "MQTT: desk 1: work_area switched off") in zone_rows(),
            "the zone switched off",
            timeout_s=20,
        )
        assert ("exit", "zone switched off by MQTT: desk 1") in zone_rows()
        control.publish(topic, "ON", qos=1).wait_for_publish(5)
        wait_until(lambda: zone_rows()[-1][0] == "zone_enabled", "on again", timeout_s=20)
        wait_until(
            lambda: log_rows(
                db,
                "SELECT 1 FROM events WHERE zone = 'work_area' AND "
                "type = 'enter' AND id > (SELECT MAX(id) FROM events WHERE "
                "type = 'zone_enabled')",
            ),
            "its people in again",
            timeout_s=20,
        )
        control.disconnect()
        control.loop_stop()

        # a broken file: the running site kept, a diagnostic incident naming the file
        site.write_text(site.read_text().replace('kind = "restricted"', 'kind = "lava"'))
        proc.send_signal(signal.SIGHUP)
        wait_until(lambda: len(_changes(db)) == 3, "the broken file said", timeout_s=30)
        _, kind, text, incident = _changes(db)[2]
        assert kind == "site_invalid" and str(site) in text and incident is not None
        assert c.get("/api/site").json()["site"]["zones"][-1]["name"] == "floor_b"
        assert proc.poll() is None
        # no camera reconnected for it (the demo's files are read on, never reopened)
        cams = c.get("/api/health").json()["cameras"]
        assert len(cams) == 4 and all(cam["reconnects"] == 0 for cam in cams.values()), cams
    finally:
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=60) == 0, (tmp_path / "serve.log").read_text()[-3000:]
        sub.close()
        broker.stop()
