"""The control room's ingest in-process against a real mosquitto: a site's last events lost
with nothing after them are found by its heartbeat; a quiet site stays live by it; the site's
clock offset is kept; malformed messages are counted; hostile ones (a corpus below) never stop
it nor cost a real site an event; names, sizes and forged ids are bounded; a thread that dies
is started again."""

from __future__ import annotations

from pathlib import Path

import paho.mqtt.client as paho
import pytest

from brokers import Broker
from stereopose.config.service import ControlRoomConfig
from stereopose.controlroom.enrolment import Enrolment, broker_hash
from stereopose.controlroom.ingest import Ingest
from stereopose.controlroom.store import ControlStore
from stereopose.io.sinks.eventwriter import SqliteSink
from stereopose.io.sinks.mqtt import MqttSettings
from stereopose.site.eventlog import EventLog
from stereopose.site.outbox import LogOutbox, OutboxPace
from stereopose.types import Event
from waiting import wait_until


def _settings(port: int, site: str = "north") -> MqttSettings:
    return MqttSettings(
        host="127.0.0.1", port=port, site=site, reconnect_min_s=0.05, reconnect_max_s=0.2
    )


def _store(tmp_path: Path, sites: tuple[str, ...] = ("north", "x")) -> ControlStore:
    """The control room's store with `sites` enrolled (no other name is stored)."""
    store = ControlStore(tmp_path / "control.sqlite")
    enrolment = Enrolment(store)
    for site in sites:
        enrolment.add(site, broker_hash("pw", iterations=1), 1.8e9)
    return store


@pytest.fixture
def broker(tmp_path: Path):
    b = Broker(tmp_path / "broker").start()
    yield b
    b.stop()


def _write(sink: SqliteSink, start: int, n: int) -> None:
    sink.write_events(
        [
            Event(
                t=k / 25,
                frame=k,
                person=1,
                zone="bus",
                kind="energized",
                type="enter",
                onset_t=k / 25,
            )
            for k in range(start, start + n)
        ]
    )


def test_the_last_events_lost_are_found_by_the_heartbeat(broker, tmp_path):
    sink = SqliteSink(tmp_path / "north.sqlite", "site.toml", "test", wall_start=1.8e9)
    log = EventLog(tmp_path / "north.sqlite")
    box = LogOutbox(_settings(broker.port), log, pace=OutboxPace(resend_s=0, heartbeat_s=0.3))
    store = _store(tmp_path)
    ingest = Ingest(_settings(broker.port, "unused"), store, replay_every_s=0.2)
    try:
        _write(sink, 1, 3)
        wait_until(lambda: store.marks().get("north") == 3, "the first events")
        ingest.close()  # the control room away: the next two reach nobody
        _write(sink, 4, 2)
        wait_until(
            lambda: box.figures()["cursor"] == 5 and box.figures()["unacknowledged"] == 0,
            "the broker taking them",
        )
        ingest = Ingest(_settings(broker.port, "unused"), store, replay_every_s=0.2)
        wait_until(lambda: ingest.subscribed, "the control room back")
        # nothing later shows the gap, and the outbox does not resend (resend_s = 0): only
        # the heartbeat's last id tells the control room they exist
        wait_until(lambda: store.marks().get("north") == 5, "the lost tail", timeout_s=20)
        assert [e["id"] for e in store.events("north", 0, 100)] == [1, 2, 3, 4, 5]
        assert ingest.figures()["behind"] >= 1, (ingest.figures(), box.figures())
        assert abs(ingest.clock_offsets["north"]) < 1.0  # one machine: the same clock
        sites = {s.site: s for s in store.sites()}
        assert sites["north"].state == "live"
    finally:
        ingest.close()
        box.close()
        sink.close()
        store.close()


def test_malformed_events_and_heartbeats_are_counted_never_stored(broker, tmp_path):
    store = _store(tmp_path)
    ingest = Ingest(_settings(broker.port, "unused"), store)
    c = paho.Client(paho.CallbackAPIVersion.VERSION2, protocol=paho.MQTTv311)
    c.connect("127.0.0.1", broker.port)
    c.loop_start()
    try:
        wait_until(lambda: ingest.subscribed, "the ingest subscribed")
        wait_until(lambda: c.is_connected(), "the client connected")
        bad = [
            ("stereopose/x/log/events", b"not json"),
            ("stereopose/x/log/events", b'{"id": "1", "prev": 0}'),
            ("stereopose/x/log/events", b'{"id": 1, "prev": -1}'),
            ("stereopose/x/log/events", b'{"id": 1, "prev": 0, "site": "y"}'),
            ("stereopose/x/log/heartbeat", b'{"last_id": "many"}'),
            ("stereopose/x/log/heartbeat", b"\xff"),
        ]
        for topic, payload in bad:
            c.publish(topic, payload, qos=1).wait_for_publish(5)
        wait_until(
            lambda: ingest.figures()["malformed"] == len(bad),
            f"each one counted {ingest.figures()}",
        )
        assert store.events(None, 0, 100) == []
    finally:
        c.loop_stop()
        c.disconnect()
        ingest.close()
        store.close()


def test_a_pruned_event_sent_again_is_not_stored_again(broker, tmp_path):
    import json

    store = _store(tmp_path)
    ingest = Ingest(_settings(broker.port, "unused"), store, ControlRoomConfig(retention_days=30))
    c = paho.Client(paho.CallbackAPIVersion.VERSION2, protocol=paho.MQTTv311)
    c.connect("127.0.0.1", broker.port)
    c.loop_start()

    def send(i: int) -> None:
        body = {"site": "x", "id": i, "prev": i - 1, "type": "enter", "zone": "bus"}
        c.publish("stereopose/x/log/events", json.dumps(body), qos=1).wait_for_publish(5)

    try:
        wait_until(lambda: ingest.subscribed, "the ingest subscribed")
        for i in (1, 2):
            send(i)
        wait_until(lambda: store.marks().get("x") == 2, "both stored")
        assert store.prune(float("inf")) == 2  # retention took them
        send(1)  # a resend of a pruned event, then a new one
        send(3)
        wait_until(lambda: store.marks().get("x") == 3, "the new one")
        assert [e["id"] for e in store.events("x")] == [3]
        assert ingest.figures()["duplicates"] == 1
    finally:
        c.loop_stop()
        c.disconnect()
        ingest.close()
        store.close()


def test_hostile_messages_never_stop_the_ingest_nor_cost_a_real_sites_events(broker, tmp_path):
    sink = SqliteSink(tmp_path / "north.sqlite", "site.toml", "test", wall_start=1.8e9)
    box = LogOutbox(
        _settings(broker.port),
        EventLog(tmp_path / "north.sqlite"),
        pace=OutboxPace(resend_s=0.5, heartbeat_s=0.3),
    )
    store = _store(tmp_path)
    ingest = Ingest(_settings(broker.port, "unused"), store, replay_every_s=0.2)
    c = paho.Client(paho.CallbackAPIVersion.VERSION2, protocol=paho.MQTTv311)
    c.connect("127.0.0.1", broker.port)
    c.loop_start()
    deep = b"[" * 20_000 + b"]" * 20_000
    hostile = [
        ("stereopose/%ZZ/log/events", b'{"id": 1, "prev": 0}'),  # a site part not valid
        ("stereopose/x/plan", deep),  # nesting past any parser's stack
        ("stereopose/x/log/events", deep),
        ("stereopose/x/log/events", b'{"id": 1, "prev": 0, "person": 18446744073709551616}'),
        ("stereopose/x/log/events", b'{"id": 1, "prev": 0, "t": Infinity}'),
        ("stereopose/x/log/events", b'{"id": 1, "prev": 0, "priority": 18446744073709551616}'),
        ("stereopose/x/log/heartbeat", b'{"last_id": Infinity, "time": 1.0}'),
        ("stereopose/x/log/heartbeat", b'{"last_id": 18446744073709551616, "time": 1.0}'),
    ]
    try:
        wait_until(lambda: ingest.subscribed and c.is_connected(), "both connected")
        for k in range(3):  # a real site writes before, between and after the attacks
            _write(sink, 1 + 3 * k, 3)
            for topic, payload in hostile:
                c.publish(topic, payload, qos=1).wait_for_publish(5)
        _write(sink, 10, 3)
        # every real event stored exactly once, the attacks counted and refused
        wait_until(lambda: store.marks().get("north") == 12, "the real site's events", timeout_s=30)
        assert [e["id"] for e in store.events("north", 0, 100)] == list(range(1, 13))
        wait_until(
            lambda: ingest.figures()["malformed"] >= 3 * (len(hostile) - 1),
            f"the attacks counted {ingest.figures()}",
        )
        assert all(e["site"] == "north" for e in store.events(None, 0, 100))
        assert "x" not in ingest.known_sites()
        assert ingest._thread.is_alive() and ingest.connected
    finally:
        c.loop_stop()
        c.disconnect()
        ingest.close()
        box.close()
        sink.close()
        store.close()


def _room_kinds(store: ControlStore) -> dict[tuple[str, str], str]:
    return {
        (i["site"], i["kind"]): i["state"]
        for i in store.incidents()
        if i["source"] == "control_room"
    }


def test_names_sizes_and_forged_ids_are_bounded_and_a_real_site_loses_nothing(broker, tmp_path):
    sink = SqliteSink(tmp_path / "north.sqlite", "site.toml", "test", wall_start=1.8e9)
    box = LogOutbox(
        _settings(broker.port),
        EventLog(tmp_path / "north.sqlite"),
        pace=OutboxPace(resend_s=0.5, heartbeat_s=0.3),
    )
    store = _store(tmp_path)
    room = ControlRoomConfig(max_event_bytes=4096, max_heartbeat_bytes=1024, ids_ahead=1000)
    ingest = Ingest(_settings(broker.port, "unused"), store, room, replay_every_s=0.2)
    c = paho.Client(paho.CallbackAPIVersion.VERSION2, protocol=paho.MQTTv311)
    c.connect("127.0.0.1", broker.port)
    c.loop_start()

    def send(topic: str, payload: bytes) -> None:
        c.publish(topic, payload, qos=1).wait_for_publish(5)

    try:
        wait_until(lambda: ingest.subscribed and c.is_connected(), "both connected")
        _write(sink, 1, 3)
        wait_until(lambda: store.marks().get("north") == 3, "the real site's first events")
        wait_until(lambda: "north" in ingest.order.announced, "the real site's heartbeat")
        # a forged id far beyond what the site announced: refused, an incident, no new mark
        send("stereopose/north/log/events", b'{"id": 9223372036854775807, "prev": 3}')
        wait_until(
            lambda: ("north", "site_ids_ahead") in _room_kinds(store), "the forged id's incident"
        )
        assert ingest.figures()["ahead"] >= 1 and store.marks()["north"] == 3
        # too large: an event, a heartbeat (its summary); a string past its bound
        send("stereopose/north/log/events", b'{"id": 4, "prev": 3, "x": "%s"}' % (b"a" * 5000))
        send(
            "stereopose/north/log/heartbeat",
            b'{"last_id": 3, "time": 1.0, "status": "%s"}' % (b"a" * 5_000_000),
        )
        send("stereopose/north/log/events", b'{"id": 4, "prev": 3, "k": ["%s"]}' % (b"b" * 4000))
        wait_until(lambda: ingest.figures()["oversize"] >= 2, "the large messages refused")
        # a heartbeat's summary holds its fields, checked, and nothing else
        send(
            "stereopose/north/log/heartbeat",
            b'{"last_id": 3, "time": 1.0, "status": "%s", "people": -1, "cameras": 4, '
            b'"junk": [1, 2, 3]}' % (b"s" * 200),
        )
        wait_until(
            lambda: (store.sites(["north"])[0].health or {}).get("cameras") == 4,
            "the checked summary stored",
        )
        # names: only the enrolled ones; 5,000 invented names are refused and counted, raise
        # one incident, take no place and are never shown offline
        for start in range(0, 5000, 500):  # in steps the broker queues for the ingest whole
            for k in range(start, start + 500):
                c.publish(f"stereopose/invented{k}/available", b"online", qos=1)
            wait_until(
                lambda n=start + 500: ingest.figures()["refused_sites"] >= n,
                f"the refusals counted up to {start + 500}",
            )
        kinds = _room_kinds(store)
        assert ("control-room", "sites_refused") in kinds
        assert [k for k in kinds if k[1] == "sites_refused"] == [("control-room", "sites_refused")]
        assert {s.site for s in store.sites()} == {"north"}
        assert not [k for k in kinds if k[1] == "site_offline"]
        # the real site goes on: every event stored once, none lost to the attacks
        _write(sink, 4, 3)
        wait_until(
            lambda: store.marks().get("north") == 6, "the real site's later events", timeout_s=30
        )
        assert [e["id"] for e in store.events("north", 0, 100)] == list(range(1, 7))
        health = store.sites(["north"])[0].health or {}
        assert "status" not in health or len(health["status"]) <= 32
        assert "junk" not in health and "people" not in health
        assert ingest.figures()["running"]
    finally:
        c.loop_stop()
        c.disconnect()
        ingest.close()
        box.close()
        sink.close()
        store.close()


@pytest.mark.filterwarnings("ignore::pytest.PytestUnhandledThreadExceptionWarning")
def test_a_dead_ingest_thread_is_started_again_and_health_says_so_meanwhile(broker, tmp_path):
    sink = SqliteSink(tmp_path / "north.sqlite", "site.toml", "test", wall_start=1.8e9)
    box = LogOutbox(
        _settings(broker.port),
        EventLog(tmp_path / "north.sqlite"),
        pace=OutboxPace(resend_s=0.5, heartbeat_s=0.3),
    )
    store = _store(tmp_path)
    ingest = Ingest(_settings(broker.port, "unused"), store, replay_every_s=0.2)
    step = ingest._step

    def dies() -> None:  # what no `except Exception` catches
        ingest._step = step
        raise SystemExit("gone")

    try:
        wait_until(lambda: ingest.subscribed, "subscribed")
        ingest._step = dies
        wait_until(lambda: not ingest._thread.is_alive(), "the thread's end")
        assert ingest.health()[0] is False and not ingest.figures()["running"]
        _write(sink, 1, 3)
        ingest.ensure_running()
        assert ingest.figures()["restarts"] == 1
        wait_until(
            lambda: store.marks().get("north") == 3, "the events after the restart", timeout_s=30
        )
        assert ingest.health() == (True, "")
        # paho's thread ended the same way: health says so, and it is started again
        message = ingest._message

        def paho_dies(*_) -> None:
            ingest._message = message
            raise SystemExit("gone")

        ingest._message = paho_dies
        _write(sink, 4, 5)  # ids 4 to 8
        wait_until(lambda: not ingest.health()[0], "health not ok while paho's thread is down")
        assert "MQTT client" in ingest.health()[1]
        ingest.ensure_running()
        assert ingest.figures()["restarts"] == 2
        wait_until(
            lambda: store.marks().get("north") == 8, "the events after paho's restart", timeout_s=30
        )
        assert ingest.health() == (True, "")
    finally:
        ingest.close()
        box.close()
        sink.close()
        store.close()
