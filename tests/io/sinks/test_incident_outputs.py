"""Incident changes out of the service: MQTT `<prefix>/<site>/incidents` (QoS 1) on a real
mosquitto, and the webhook (a real local receiver) marked apart from the events; the event
topic and the webhook's events unchanged beside them."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from brokers import Broker, Subscriber, free_port
from receivers import Receiver
from stereopose.alarms import IncidentBook
from stereopose.io.sinks.mqtt import MqttSettings, MqttSink
from stereopose.io.sinks.webhook import WebhookSink
from stereopose.types import Event
from waiting import wait_until

BASE = "stereopose/yard"


@pytest.fixture
def broker(tmp_path: Path):
    b = Broker(tmp_path / "broker").start()
    yield b
    b.stop()


def _changes() -> tuple[list[Event], list]:
    """A reach into a panel twice, then the exit, and an operator's ack: its changes."""
    book = IncidentBook()
    enter = [
        Event(
            t=float(k), frame=k, person=3, zone="panel", kind="energized", type=t, onset_t=float(k)
        )
        for k, t in ((1, "enter"), (2, "exit"), (3, "enter"), (4, "exit"))
    ]
    changes = []
    for e in enter:
        changes += book.update([e], e.t).changes
    changes += book.acknowledge(1, "otto", 5.0)
    return enter, changes


def test_incidents_topic_each_change_qos1_beside_the_events(broker, tmp_path) -> None:
    sub = Subscriber(broker.port, f"{BASE}/#")
    sink = MqttSink(
        MqttSettings(host="127.0.0.1", port=broker.port, site="yard", close_timeout_s=3.0)
    )
    try:
        events, changes = _changes()
        sink.write_events(events)
        sink.write_changes(changes)
        topic = f"{BASE}/incidents"
        wait_until(lambda: len(sub.on(topic)) >= len(changes), "every incident change")
        got = [json.loads(p) for p in sub.on(topic)]
        assert [g["change"] for g in got] == [c.what for c in changes]
        assert [g["change"] for g in got] == [
            "raised",
            "cleared",
            "occurrence",
            "cleared",
            "acknowledged",
        ]
        assert {g["incident"]["id"] for g in got} == {1}
        assert got[-1]["state"] == "closed" and got[-1]["by"] == "otto"
        assert got[-1]["incident"]["occurrences"] == 2
        wait_until(lambda: len(sub.on(f"{BASE}/events")) >= 4, "the events still published")
    finally:
        sink.close()
        sub.close()
    assert sink.figures()["incidents"]["published"] == len(changes)


def test_webhook_gets_incident_changes_marked_apart() -> None:
    receiver = Receiver()
    hook = WebhookSink(receiver.url)
    try:
        events, changes = _changes()
        hook.write_events(events[:1])
        hook.write_changes(changes)
        wait_until(lambda: len(receiver.bodies) >= 1 + len(changes), "every body")
    finally:
        hook.close()
        receiver.close()
    first, *rest = receiver.bodies
    assert "incident_change" not in first and first["type"] == "enter"
    assert all(b["incident_change"] is True for b in rest)
    # a receiver reading every body as an event sees a type it does not know, never none
    assert {(b["type"], b["kind"]) for b in rest} == {("incident_change", "incident")}
    assert [b["change"] for b in rest] == [c.what for c in changes]
    assert rest[0]["incident"]["priority"] == 1


def test_every_alarm_output_implements_the_one_interface_and_the_log_stores_changes(
    broker, tmp_path
) -> None:
    """The event log, the webhook, MQTT and the IEC 104 outstation as AlarmOutput: the same
    members, figures as a dict, and the event log's write_changes storing each incident."""
    from stereopose.io.sinks import SqliteSink
    from stereopose.io.sinks.health import AlarmOutput
    from stereopose.site.eventlog import EventLog

    rx = Receiver()
    db = SqliteSink(tmp_path / "events.sqlite", "site.toml", "test", wall_start=1.8e9)
    outs = [
        db,
        WebhookSink(rx.url),
        MqttSink(MqttSettings(host="127.0.0.1", port=broker.port, site="yard"), ["panel"]),
    ]
    try:
        import c104  # noqa: F401

        from stereopose.config import Iec104Config
        from stereopose.fence import Site, Zone
        from stereopose.scada.iec104 import Iec104Settings, Outstation
        from stereopose.scada.points import points_table
        from stereopose.sim.scene import make_rig

        rig = make_rig(2, np.random.default_rng(3), (12.0, 8.0, 4.0))
        square = np.array([[5.5, 3.5], [6.5, 3.5], [6.5, 4.5], [5.5, 4.5]])
        site = Site((Zone("panel", "energized", square, (0.0, 2.5)),), 25.0)
        settings = Iec104Settings.from_config(Iec104Config(enabled=True, port=free_port()))
        outs.append(Outstation(settings, points_table(site, rig), wall_start=1.8e9))
    except ImportError:
        pass
    try:
        names = set()
        enter, changes = _changes()
        for out in outs:
            assert isinstance(out, AlarmOutput), out
            names.add(out.output_name)
            assert isinstance(out.label, str) and out.label
            out.write_changes(changes)
            assert isinstance(out.figures(), dict)
            assert isinstance(out.queued(), int) and isinstance(out.dropped, int)
            ok, waiting, _ = out.health()
            assert isinstance(ok, bool) and isinstance(waiting, int)
        assert {"events_db", "webhook", "mqtt"} <= names and len(names) == len(outs)
        db.write_events(enter)  # the incident records go in with the events' transaction
        stored = EventLog(tmp_path / "events.sqlite").incident_changes_after(0)
        assert [c["incident"]["id"] for c in stored] == [1]
        assert stored[-1]["incident"]["acked_by"] == "otto"
    finally:
        for out in outs:
            out.close()
        rx.close()
