"""Sites enrolled in the control room (`control-room sites add|list|remove`,
`control-room broker-config`): the only names it stores, each with its own login on a real
central mosquitto that runs the password file and ACL the command writes. An enrolled site's
events are stored; another site's login cannot publish as it, nor under invented names; a site
enrolled while the room runs is stored at once; a removed one is refused; a store from before
enrolment keeps its sites; bad input is exit 2 with the reason."""

from __future__ import annotations

import re
import signal
import subprocess
import sys
from pathlib import Path

import paho.mqtt.client as paho
import pytest
from test_control_room import ENV, Site, _add_user, _central, _client, _start

from brokers import Broker, free_port
from stereopose.controlroom.broker_config import acl_text
from stereopose.controlroom.enrolment import Enrolment, broker_hash, check_name
from stereopose.controlroom.store import ControlStore
from stereopose.errors import ConfigError
from waiting import wait_until

PACKAGING = Path(__file__).resolve().parents[2] / "packaging" / "mosquitto"


def _cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "stereopose.cli", "control-room", *args],
        capture_output=True,
        text=True,
        env=ENV,
    )


def _passwords(stdout: str) -> list[str]:
    return re.findall(r"remote_password (\S+)", stdout)


def _room(folder: Path, broker_port: int, http_port: int) -> Path:
    folder.mkdir(parents=True)
    (folder / "mqtt.secret").write_text("room-pw\n")
    (folder / "mqtt.secret").chmod(0o600)
    config = folder / "control.toml"
    config.write_text(
        f'output = "data"\n\n[serve]\nport = {http_port}\n\n[mqtt]\nhost = "127.0.0.1"\n'
        f'port = {broker_port}\nusername = "control-room"\npassword_file = "mqtt.secret"\n'
    )
    return config


def _enrolled(c) -> int:
    return c.get("/api/health").json()["ingest"]["enrolled"]


def _login(port: int, user: str, password: str) -> paho.Client:
    c = paho.Client(paho.CallbackAPIVersion.VERSION2, protocol=paho.MQTTv311)
    c.username_pw_set(user, password)
    c.connect("127.0.0.1", port)
    c.loop_start()
    wait_until(c.is_connected, f"{user} connected")
    return c


@pytest.mark.slow
def test_only_enrolled_sites_each_with_its_own_login_on_a_real_broker(tmp_path):
    broker = Broker(tmp_path / "central")
    files = tmp_path / "broker-files"
    http_port = free_port()
    config = _room(tmp_path / "room", broker.port, http_port)
    added = _cli("sites", "add", "north", "south", "--config", str(config))
    assert added.returncode == 0, added.stdout + added.stderr
    north_pw, south_pw = _passwords(added.stdout)
    assert north_pw != south_pw
    made = _cli("broker-config", "--config", str(config), "--out", str(files))
    assert made.returncode == 0, made.stdout + made.stderr
    assert (files / "passwd").stat().st_mode & 0o077 == 0
    passwd = (files / "passwd").read_text()
    assert north_pw not in passwd and "room-pw" not in passwd  # hashes only
    assert {line.split(":")[0] for line in passwd.split()} == {
        "control-room",
        "site-north",
        "site-south",
    }
    for f in (config.parent / "data").rglob("*"):  # the store keeps no password
        if f.is_file():
            assert north_pw.encode() not in f.read_bytes()
    text = broker.config.read_text().replace("allow_anonymous true", "allow_anonymous false")
    broker.config.write_text(
        text + f"password_file {files / 'passwd'}\nacl_file {files / 'central-acl'}\n"
    )
    broker.start()
    _add_user(config)
    room = _start(config, tmp_path / "room.log")
    north = Site(tmp_path, "north", broker.port, username="site-north", password=north_pw)
    east = south = None
    intruder = _login(broker.port, "site-south", south_pw)
    try:
        c = _client(http_port)
        north.write(5)
        wait_until(lambda: _central(c, "north") == north.ids(), "north's events", timeout_s=30)
        # south's login publishing as north, and under 5,000 invented names: the broker's ACL
        # drops every one; the room never sees them
        forged = b'{"site": "north", "id": 6, "prev": 5, "type": "enter", "zone": "forged"}'
        intruder.publish("stereopose/north/log/events", forged, qos=1).wait_for_publish(5)
        for k in range(5000):
            intruder.publish(f"stereopose/invented{k}/available", b"online", qos=1)
        intruder.publish("stereopose/invented/log/events", forged, qos=1).wait_for_publish(10)
        north.write(3)
        wait_until(lambda: _central(c, "north") == north.ids(), "north's later events")
        stored = c.get("/api/events", params={"site": "north", "limit": 100}).json()["events"]
        assert "forged" not in {e.get("zone") for e in stored}
        health = c.get("/api/health").json()
        assert health["ingest"]["refused_sites"] == 0, health
        assert {s["site"] for s in c.get("/api/sites").json()["sites"]} == {"north"}
        # a site enrolled while the room runs: its login written, the broker reloaded
        more = _cli(
            "sites", "add", "east", "--config", str(config), "--bridge", str(tmp_path / "b")
        )
        assert more.returncode == 0, more.stdout + more.stderr
        (east_pw,) = _passwords(more.stdout)
        bridge = (tmp_path / "b").read_text()
        assert f"remote_password {east_pw}" in bridge and "remote_username site-east" in bridge
        assert "topic stereopose/east/log/events out 1" in bridge and "SITE" not in bridge
        assert _cli("broker-config", "--config", str(config), "--out", str(files)).returncode == 0
        broker.proc.send_signal(signal.SIGHUP)
        wait_until(lambda: _enrolled(c) == 3, "the room taking east")
        east = Site(tmp_path, "east", broker.port, username="site-east", password=east_pw)
        east.write(4)
        wait_until(lambda: _central(c, "east") == east.ids(), "east's events", timeout_s=30)
        # south removed: its own messages are refused by the room (its login still works)
        gone = _cli("sites", "remove", "south", "--config", str(config))
        assert gone.returncode == 0, gone.stdout + gone.stderr
        listed = _cli("sites", "list", "--config", str(config))
        assert [line.split()[0] for line in listed.stdout.splitlines()] == ["east", "north"]
        wait_until(lambda: _enrolled(c) == 2, "the room refusing south")
        south = Site(tmp_path, "south", broker.port, username="site-south", password=south_pw)
        south.write(2)
        wait_until(
            lambda: c.get("/api/health").json()["ingest"]["refused_sites"] >= 1,
            "south's messages refused",
            timeout_s=30,
        )
        assert "south" not in {s["site"] for s in c.get("/api/sites").json()["sites"]}
        assert _central(c, "south") == []
        assert room.poll() is None
    finally:
        intruder.loop_stop()
        intruder.disconnect()
        for s in (north, east, south):
            if s is not None:
                s.close()
        room.terminate()
        room.wait(timeout=30)
        broker.stop()


def test_a_store_from_before_enrolment_keeps_its_sites(tmp_path):
    store = ControlStore(tmp_path / "control.sqlite")
    try:
        store.set_site("old")  # stored by a version without enrolment
        assert Enrolment(store).names() == {"old"}
        store.set_site("later")  # a site row made later is not enrolled by it
        enrolment = Enrolment(store)
        assert enrolment.names() == {"old"}
        assert [(r.site, r.has_login) for r in enrolment.list()] == [("old", False)]
        assert enrolment.add("old", broker_hash("pw", iterations=1), 1.0) is False
        assert enrolment.logins()[0][0] == "old"
        assert enrolment.remove("old") and not enrolment.remove("old")
    finally:
        store.close()


def test_the_acl_and_hashes_are_mosquittos():
    shipped = (PACKAGING / "central-acl").read_text()
    block = re.search(r"^user site-north\n(?:topic .*\n)+", shipped, re.M).group(0)
    assert block.strip() in acl_text("stereopose", "control-room", ["north"])
    slashed = acl_text("stereopose", "r", ["south/yard"])
    assert "topic write stereopose/south%2Fyard/log/events" in slashed
    h = broker_hash("secret123", salt=bytes(12), iterations=101)
    assert h.startswith("$7$101$AAAAAAAAAAAAAAAA$")
    for bad in ("", "a b", "a:b", "x" * 65, "tab\there"):
        with pytest.raises(ConfigError, match="site name"):
            check_name(bad)


def test_bad_enrolment_commands_are_exit_2_with_the_reason(tmp_path):
    config = tmp_path / "control.toml"
    config.write_text('output = "data"\n\n[mqtt]\nhost = "127.0.0.1"\n')
    cases = [
        (("sites", "add", "north"), "--config"),
        (("sites", "add", "a:b", "--config", str(config)), "site name"),
        (("sites", "add", "--config", str(config)), "give the site's NAME"),
        (("sites", "list", "north", "--config", str(config)), "takes no NAME"),
        (("sites", "move", "--config", str(config)), "(choose from 'add', 'list', 'remove')"),
        (("sites",), "VERB"),
        (("run",), "CONFIG.toml"),
        (("sites", "remove", "nobody", "--config", str(config)), "not enrolled: nobody"),
        (("broker-config", "--config", str(config)), "--out"),
        (("broker-config", "--config", str(config), "--out", str(tmp_path / "b")), "username"),
        (("a.toml", "b.toml"), "one configuration file"),
    ]
    for args, reason in cases:
        r = _cli(*args)
        assert r.returncode == 2, (args, r.stdout, r.stderr)
        assert reason in r.stdout + r.stderr, (args, r.stdout, r.stderr)
        assert "Traceback" not in r.stdout + r.stderr


def test_each_action_and_verb_has_its_own_help_and_the_old_form_still_runs(tmp_path):
    for args, says in (
        (("--help",), ("run", "sites", "broker-config")),
        (("sites", "--help"), ("add", "list", "remove")),
        (("sites", "add", "--help"), ("--bridge", "--config", "NAME")),
        (("sites", "list", "--help"), ("--config",)),
        (("sites", "remove", "--help"), ("--config", "NAME")),
        (("broker-config", "--help"), ("--config", "--out")),
        (("run", "--help"), ("CONFIG.toml",)),
    ):
        r = _cli(*args)
        assert r.returncode == 0 and all(s in r.stdout for s in says), (args, r.stdout)
    # `control-room CONFIG.toml` is `control-room run CONFIG.toml`: the same refusal of a
    # configuration that is not there, naming it
    for args in (("nowhere.toml",), ("run", "nowhere.toml")):
        r = _cli(*args)
        assert r.returncode == 2 and "nowhere.toml" in r.stdout + r.stderr, (args, r.stdout)
