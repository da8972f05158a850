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

import paho.mqtt.client as paho
import pytest
from test_control_room import ENV, _add_user, _central, _client

from brokers import Broker, free_port, make_certificate
from stereopose.io.sinks.events import SqliteSink
from stereopose.io.sinks.mqtt import MqttSettings
from stereopose.service.eventlog import EventLog
from stereopose.service.outbox import LogOutbox
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


def test_a_bridged_site_reaches_the_control_room_once_across_a_cut(tmp_path):
    cert, key = make_certificate(tmp_path, "central")
    users = {"site-north": "north-pw", "site-south": "south-pw", "control-room": "room-pw"}
    central = Broker(tmp_path / "central", users=users, tls=(cert, key),
                     extra=(f"acl_file {_acl(tmp_path)}",)).start()  # fmt: skip
    site_broker = Broker(tmp_path / "site", extra=tuple(_bridge(cert, central.port,
                                                                "north-pw"))).start()  # fmt: skip
    http_port = free_port()
    room_dir = tmp_path / "room"
    room_dir.mkdir()
    (room_dir / "mqtt.secret").write_text("room-pw\n")
    (room_dir / "mqtt.secret").chmod(0o600)
    config = room_dir / "control.toml"
    config.write_text(f'output = "data"\n\n[serve]\nport = {http_port}\n\n[mqtt]\n'
                      f'host = "localhost"\nport = {central.port}\ntls = true\n'
                      f'ca_file = "{cert}"\nusername = "control-room"\n'
                      'password_file = "mqtt.secret"\n')  # fmt: skip
    _add_user(config)
    sink = SqliteSink(tmp_path / "north.sqlite", "site.toml", "test", wall_start=1.8e9)
    log = EventLog(tmp_path / "north.sqlite")
    box = LogOutbox(MqttSettings(host="127.0.0.1", port=site_broker.port, site="north",
                                 reconnect_min_s=0.05, reconnect_max_s=0.2), log,
                    resend_s=2.0)  # fmt: skip
    k = 0

    def write(n: int) -> None:
        nonlocal k
        evs = []
        for _ in range(n):
            k += 1
            evs.append(Event(t=k / 25, frame=k, person=1, zone="bus", kind="energized",
                             type="enter", onset_t=k / 25))  # fmt: skip
        sink.write_events(evs)

    def ids() -> list[int]:
        return [e["id"] for e in log.after(0, limit=100_000)]

    with open(tmp_path / "room.log", "ab") as f:
        cmd = [sys.executable, "-m", "stereopose.cli", "control-room", str(config)]
        room = subprocess.Popen(cmd, stdout=f, stderr=subprocess.STDOUT, env=ENV)
    try:
        c = _client(http_port)
        write(10)
        wait_until(lambda: _central(c, "north") == ids(), "the site's events through the bridge",
                   timeout_s=60)  # fmt: skip
        central.stop()  # the link is cut: the bridge and the control room lose the central side
        cut = time.monotonic()
        while time.monotonic() - cut < 5:
            write(3)
            time.sleep(0.5)
        central.start()
        write(2)
        wait_until(lambda: _central(c, "north") == ids(), "every event after the cut",
                   timeout_s=60)  # fmt: skip
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
