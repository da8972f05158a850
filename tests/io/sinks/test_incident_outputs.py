"""Incident changes out of the service: MQTT `<prefix>/<site>/incidents` (QoS 1) on a real
mosquitto, and the webhook (a real local receiver) marked apart from the events; the event
topic and the webhook's events unchanged beside them."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from brokers import Broker, Subscriber
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
    enter = [Event(t=float(k), frame=k, person=3, zone="panel", kind="energized", type=t,
                   onset_t=float(k)) for k, t in ((1, "enter"), (2, "exit"), (3, "enter"),
                                                   (4, "exit"))]  # fmt: skip
    changes = []
    for e in enter:
        changes += book.update([e], e.t).changes
    changes += book.acknowledge(1, "otto", 5.0)
    return enter, changes


def test_incidents_topic_each_change_qos1_beside_the_events(broker, tmp_path) -> None:
    sub = Subscriber(broker.port, f"{BASE}/#")
    sink = MqttSink(MqttSettings(host="127.0.0.1", port=broker.port, site="yard",
                                 close_timeout_s=3.0))  # fmt: skip
    try:
        events, changes = _changes()
        sink.write_events(events)
        sink.write_changes(changes)
        topic = f"{BASE}/incidents"
        wait_until(lambda: len(sub.on(topic)) >= len(changes), "every incident change")
        got = [json.loads(p) for p in sub.on(topic)]
        assert [g["change"] for g in got] == [c.what for c in changes]
        assert [g["change"] for g in got] == ["raised", "cleared", "occurrence", "cleared",
                                              "acknowledged"]  # fmt: skip
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
