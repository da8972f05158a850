"""The shipped bridge configuration (packaging/mosquitto/) with real brokers: a site's
mosquitto bridged over TLS to the central one with the shipped ACL; the control room on the
central broker stores every event of the site once across a cut of the central side, and a
site's login cannot publish as another site."""

from __future__ import annotations

import json
import re
import subprocess
import sys
import time
from pathlib import Path

import httpx
import paho.mqtt.client as paho
import pytest
from test_control_room import ENV, _add_user, _central, _client, _enrol

from brokers import Broker, free_port, make_certificate
from stereopose.io.sinks.eventwriter import SqliteSink
from stereopose.io.sinks.mqtt import MqttSettings
from stereopose.site.eventlog import EventLog
from stereopose.site.outbox import LogOutbox, OutboxPace
from stereopose.types import Event
from waiting import wait_until

pytestmark = pytest.mark.slow

PACKAGING = Path(__file__).resolve().parents[2] / "packaging" / "mosquitto"


def _acl(folder: Path) -> Path:
    """The shipped ACL, with a second site's block made from the first, as its comment says."""
    text = (PACKAGING / "central-acl").read_text()
    block = re.search(r"^user site-north\n(?:topic .*\n)+", text, re.M).group(0)
    path = folder / "central-acl"
    path.write_text(text + "\n" + block.replace("north", "south"))
    return path


def _bridge(cert: Path, central_port: int, password: str) -> list[str]:
    """The shipped site bridge for site `north`, pointed at the test's central broker."""
    text = (PACKAGING / "site-bridge.conf").read_text().replace("SITE", "north")
    text = text.replace("central.example.org:8883", f"localhost:{central_port}")
    text = text.replace("CHANGE-ME", password)
    text = text.replace("/etc/mosquitto/certs/central-ca.pem", str(cert))
    text = text.replace("restart_timeout 2 30", "restart_timeout 1 2")  # a quick test
    return [line for line in text.splitlines() if line and not line.startswith("#")]


def _brokers(tmp_path: Path, cert: Path, key: Path, users: dict[str, str]) -> tuple:
    """The central broker (TLS, logins, the shipped ACL) and the site's, bridged to it."""
    central = Broker(
        tmp_path / "central", users=users, tls=(cert, key), extra=(f"acl_file {_acl(tmp_path)}",)
    ).start()
    site = Broker(tmp_path / "site", extra=tuple(_bridge(cert, central.port, "north-pw")))
    return central, site.start()


def _room_config(
    room_dir: Path, central_port: int, cert: Path, http_port: int, extra: str = ""
) -> Path:
    """A control room's configuration on the central broker, its login in a secret file."""
    room_dir.mkdir()
    (room_dir / "mqtt.secret").write_text("room-pw\n")
    (room_dir / "mqtt.secret").chmod(0o600)
    config = room_dir / "control.toml"
    config.write_text(
        f'output = "data"\n\n[serve]\nport = {http_port}\n\n[mqtt]\n'
        f'host = "localhost"\nport = {central_port}\ntls = true\n'
        f'ca_file = "{cert}"\nusername = "control-room"\n'
        f'password_file = "mqtt.secret"\n\n{extra}'
    )
    return config


def test_a_bridged_site_reaches_the_control_room_once_across_a_cut(tmp_path):
    cert, key = make_certificate(tmp_path, "central")
    users = {"site-north": "north-pw", "site-south": "south-pw", "control-room": "room-pw"}
    central, site_broker = _brokers(tmp_path, cert, key, users)
    http_port = free_port()
    config = _room_config(tmp_path / "room", central.port, cert, http_port)
    _add_user(config)
    _enrol(config, "north")
    sink = SqliteSink(tmp_path / "north.sqlite", "site.toml", "test", wall_start=1.8e9)
    log = EventLog(tmp_path / "north.sqlite")
    box = LogOutbox(
        MqttSettings(
            host="127.0.0.1",
            port=site_broker.port,
            site="north",
            reconnect_min_s=0.05,
            reconnect_max_s=0.2,
        ),
        log,
        pace=OutboxPace(resend_s=2.0),
    )
    k = 0

    def write(n: int) -> None:
        nonlocal k
        evs = []
        for _ in range(n):
            k += 1
            evs.append(
                Event(
                    t=k / 25,
                    frame=k,
                    person=1,
                    zone="bus",
                    kind="energized",
                    type="enter",
                    onset_t=k / 25,
                )
            )
        sink.write_events(evs)

    def ids() -> list[int]:
        return [e["id"] for e in log.after(0, limit=100_000)]

    with open(tmp_path / "room.log", "ab") as f:
        cmd = [sys.executable, "-m", "stereopose.cli", "control-room", str(config)]
        room = subprocess.Popen(cmd, stdout=f, stderr=subprocess.STDOUT, env=ENV)
    try:
        c = _client(http_port)
        write(10)
        wait_until(
            lambda: _central(c, "north") == ids(),
            "the site's events through the bridge",
            timeout_s=60,
        )
        central.stop()  # the link is cut: the bridge and the control room lose the central side
        cut = time.monotonic()
        while time.monotonic() - cut < 5:
            write(3)
            time.sleep(0.5)
        central.start()
        write(2)
        wait_until(lambda: _central(c, "north") == ids(), "every event after the cut", timeout_s=60)
        assert len(ids()) >= 40 and len(set(_central(c, "north"))) == len(ids())
        # the ACL: north's login cannot publish as south
        forger = paho.Client(paho.CallbackAPIVersion.VERSION2, protocol=paho.MQTTv311)
        forger.username_pw_set("site-north", "north-pw")
        forger.tls_set(ca_certs=str(cert))
        forger.connect("localhost", central.port)
        forger.loop_start()
        forged = {"site": "south", "id": 1, "prev": 0, "type": "enter", "zone": "x"}
        forger.publish("stereopose/south/log/events", json.dumps(forged), qos=1).wait_for_publish(5)
        write(1)  # a real one after it, to know the control room read past it
        wait_until(lambda: _central(c, "north") == ids(), "the last event", timeout_s=30)
        assert "south" not in {s["site"] for s in c.get("/api/sites").json()["sites"]}
        forger.loop_stop()
        forger.disconnect()
    finally:
        room.terminate()
        room.wait(timeout=30)
        box.close()
        sink.close()
        site_broker.stop()
        central.stop()


def _ids(db: Path) -> list[int]:
    import sqlite3

    if not db.exists():
        return []
    con = sqlite3.connect(f"file:{db}?mode=ro", uri=True, timeout=5)
    try:
        return [i for (i,) in con.execute("SELECT id FROM events ORDER BY id")]
    except sqlite3.OperationalError:
        return []
    finally:
        con.close()


@pytest.mark.realdata
def test_a_served_bridged_site_across_a_60_s_cut_a_control_room_kill_and_acks_both_ways(tmp_path):
    """The issue's whole scene: a site `serve` on the demo, its mosquitto bridged (the
    shipped configuration) to the central one, the control room on the central one. During a
    60-s cut of the central side the control room is killed and started again, an operator
    acknowledges an incident in the control room and another at the site; once the link is
    back both acknowledgements are on both sides, every event of the site's log is stored
    centrally once, and the site stopped is shown offline within its allowance."""
    import signal

    from test_control_room import _add, _login

    from stereopose.pipeline.demo import write_serve_demo_config

    cert, key = make_certificate(tmp_path, "central")
    users = {"site-north": "north-pw", "control-room": "room-pw"}
    central, site_broker = _brokers(tmp_path, cert, key, users)
    http_port, site_port = free_port(), free_port()
    config = _room_config(
        tmp_path / "room",
        central.port,
        cert,
        http_port,
        "[control_room]\noffline_after_s = 30\ncommand_resend_s = 2\n",
    )
    _add_user(config)
    _add(config, "olga", "operator")
    _enrol(config, "north")
    site_config = write_serve_demo_config(
        tmp_path / "demo", tmp_path / "data", site_port, imgsz=320
    )
    site_config.write_text(
        site_config.read_text().replace(
            "[serve]\n",
            f'[mqtt]\nhost = "127.0.0.1"\nport = {site_broker.port}\nsite = "north"\n'
            "outbox_resend_s = 5\n\n[serve]\n",
            1,
        )
    )
    _add(site_config, "sam", "operator")
    db = tmp_path / "data" / "events.sqlite"

    def start_room() -> subprocess.Popen:
        with open(tmp_path / "room.log", "ab") as f:
            cmd = [sys.executable, "-m", "stereopose.cli", "control-room", str(config)]
            return subprocess.Popen(cmd, stdout=f, stderr=subprocess.STDOUT, env=ENV)

    room = start_room()
    with open(tmp_path / "serve.log", "ab") as f:
        serve = subprocess.Popen(
            [sys.executable, "-m", "stereopose.cli", "serve", str(site_config)],
            stdout=f,
            stderr=subprocess.STDOUT,
            env=ENV,
        )
    try:
        c = _client(http_port)
        olga = _login(http_port, "olga", "olga-password")

        def site_up() -> bool:
            try:
                return httpx.get(f"http://127.0.0.1:{site_port}/api/health").status_code < 500
            except httpx.HTTPError:
                return False

        wait_until(site_up, "the site's API", timeout_s=120, poll_s=0.5)
        sam = _login(site_port, "sam", "sam-password")

        def central_incidents() -> dict[int, dict]:
            found = c.get("/api/incidents", params={"site": "north"}).json()["incidents"]
            return {i["id"]: i for i in found if i["source"] == "site"}

        def unacked() -> list[int]:
            return sorted(i for i, r in central_incidents().items() if not r.get("acked_by"))

        wait_until(
            lambda: len(unacked()) >= 2,
            "two incidents in the control room",
            timeout_s=180,
            poll_s=0.5,
        )
        first, second = unacked()[:2]
        central.stop()  # the cut: the bridge and the control room lose the central side
        cut = time.monotonic()
        r = olga.post(f"/api/sites/north/incidents/{first}/ack")
        assert r.status_code == 202, r.text
        r = sam.post(f"/api/incidents/{second}/ack")
        assert r.status_code == 200, r.text
        room.send_signal(signal.SIGKILL)  # and the control room dies in the middle of it
        room.wait(timeout=10)
        room = start_room()
        c, olga = _client(http_port), _login(http_port, "olga", "olga-password")
        time.sleep(max(0.0, 60 - (time.monotonic() - cut)))  # the cut lasts its 60 s
        central.start()

        def site_record(i: int) -> dict:
            found = sam.get("/api/incidents", params={"limit": 1000}).json()["incidents"]
            return next(r for r in found if r["id"] == i)

        wait_until(
            lambda: site_record(first).get("acked_by") == "olga via control-room",
            "the control room's ack at the site",
            timeout_s=60,
            poll_s=0.5,
        )
        wait_until(
            lambda: central_incidents()[second].get("acked_by") == "sam",
            "the site's ack in the control room",
            timeout_s=60,
            poll_s=0.5,
        )
        wait_until(
            lambda: central_incidents()[first].get("acked_by") == "olga via control-room",
            "the control room's ack back",
            timeout_s=60,
            poll_s=0.5,
        )
        site = next(s for s in c.get("/api/sites").json()["sites"] if s["site"] == "north")
        assert site["state"] in ("live", "degraded") and site["cameras"] == 4
        # what the bridge dropped while cut is sent again from the site's log
        logged = _ids(db)
        wait_until(
            lambda: set(logged) <= set(_central(c, "north")),
            "the events of the cut in the control room",
            timeout_s=60,
            poll_s=0.5,
        )
        serve.send_signal(signal.SIGTERM)
        assert serve.wait(timeout=60) == 0, (tmp_path / "serve.log").read_text()[-3000:]
        stopped = time.monotonic()

        def central_ids() -> list[int]:
            return _central(c, "north")

        wait_until(
            lambda: central_ids() == _ids(db),
            "every event of the site, once",
            timeout_s=60,
            poll_s=0.5,
        )

        def state() -> str:
            return next(s for s in c.get("/api/sites").json()["sites"] if s["site"] == "north")[
                "state"
            ]

        # offline within its allowance (offline_after_s 30) and the ingest's check, from the stop
        allowance = stopped + 30 + 15 - time.monotonic()
        wait_until(
            lambda: state() == "offline",
            "the site offline within its allowance",
            timeout_s=max(allowance, 1.0),
            poll_s=0.5,
        )
        offline = [
            i
            for i in c.get("/api/incidents", params={"site": "north"}).json()["incidents"]
            if i.get("kind") == "site_offline"
        ]
        assert offline and offline[0]["state"] == "active"
    finally:
        if serve.poll() is None:
            serve.kill()
        room.terminate()
        room.wait(timeout=30)
        site_broker.stop()
        central.stop()
