"""Zones switched off and on over MQTT (io.sinks.mqtt_commands) against a real mosquitto:
each form of command taken with who sent it, anything else refused and counted, the receiver
alive after any message, subscribed again after the broker restarts."""

from __future__ import annotations

import json
import threading
from pathlib import Path

import paho.mqtt.client as paho
import pytest
from hypothesis import given
from hypothesis import strategies as st

from brokers import Broker
from stereopose.errors import ConfigError
from stereopose.io.sinks.mqtt import MqttSettings, MqttSink, topic_part
from stereopose.io.sinks.mqtt_commands import MAX_PAYLOAD, parse_switch
from waiting import wait_until

SITE = "north/yard"
BASE = "stereopose/north%2Fyard"
ZONES = ("bay 2/a", "bench")


class Desk:
    """What a site desk's switch_zone does with a command: takes it, or refuses a zone the
    site does not have."""

    def __init__(self) -> None:
        self.taken: list[tuple[str, bool, str]] = []
        self.lock = threading.Lock()

    def switch_zone(self, zone: str, on: bool, by: str) -> None:
        if zone not in ZONES:
            raise ConfigError(f"zone {zone!r}: no such zone in the site")
        with self.lock:
            self.taken.append((zone, on, by))


@pytest.fixture
def broker(tmp_path: Path):
    b = Broker(tmp_path / "broker").start()
    yield b
    b.stop()


def _settings(port: int) -> MqttSettings:
    return MqttSettings(
        host="127.0.0.1", port=port, site=SITE, reconnect_min_s=0.05, reconnect_max_s=0.2
    )


def _publisher(port: int) -> paho.Client:
    c = paho.Client(paho.CallbackAPIVersion.VERSION2, protocol=paho.MQTTv311)
    c.connect("127.0.0.1", port)
    c.loop_start()
    return c


def _send(c: paho.Client, zone: str, payload: bytes | str) -> None:
    topic = f"{BASE}/zones/{topic_part(zone)}/enabled"
    c.publish(topic, payload, qos=1).wait_for_publish(5)


def test_every_form_is_taken_with_who_sent_it_and_the_rest_refused(broker) -> None:
    desk = Desk()
    sink = MqttSink(_settings(broker.port), ZONES, desk.switch_zone)
    c = _publisher(broker.port)
    try:
        wait_until(lambda: sink.commands.client.is_connected(), "the commands' link")
        warm = json.dumps({"enabled": True, "by": "warm-up"})  # until subscribed: told apart
        wait_until(lambda: _send(c, "bench", warm) or desk.taken, "the first command", timeout_s=10)
        good = [
            ("bay 2/a", "OFF"),
            ("bay 2/a", "on"),
            ("bench", "false"),
            ("bench", "1"),
            ("bay 2/a", json.dumps({"enabled": False, "by": "control desk"})),
        ]
        bad = [
            ("bay9", "OFF"),  # no such zone
            ("bench", "maybe"),
            ("bench", b"\xff\xfe"),
            ("bench", json.dumps({"enabled": "no"})),
            ("bench", json.dumps({"enabled": True, "by": "x" * 65})),
            ("bench", json.dumps({"enabled": True, "by": "tab\there"})),
            ("bench", "ON" + " " * MAX_PAYLOAD),
            ("bench", json.dumps([1, 2])),
        ]
        for zone, payload in bad[:4] + good[:3] + bad[4:] + good[3:]:
            _send(c, zone, payload)

        def taken() -> list:
            return [t for t in desk.taken if t[2] != "MQTT: warm-up"]

        wait_until(lambda: len(taken()) == len(good), "every good command")
        wait_until(lambda: sink.commands.counts["refused"] == len(bad), "every bad one counted")
        assert taken() == [
            ("bay 2/a", False, "MQTT"),
            ("bay 2/a", True, "MQTT"),
            ("bench", False, "MQTT"),
            ("bench", True, "MQTT"),
            ("bay 2/a", False, "MQTT: control desk"),
        ]
        wait_until(lambda: sink.commands.counts["taken"] == len(desk.taken), "all counted")
    finally:
        c.loop_stop()
        sink.close()


def test_without_a_switch_no_command_is_listened_to(broker) -> None:
    sink = MqttSink(_settings(broker.port), ZONES)
    try:
        assert sink.commands is None
    finally:
        sink.close()


def test_commands_are_taken_again_after_the_broker_restarts(tmp_path: Path) -> None:
    b = Broker(tmp_path / "broker").start()
    desk = Desk()
    sink = MqttSink(_settings(b.port), ZONES, desk.switch_zone)
    try:
        c = _publisher(b.port)
        wait_until(lambda: _send(c, "bench", "OFF") or desk.taken, "a command", timeout_s=10)
        c.loop_stop()
        b.stop()
        b.start()
        c = _publisher(b.port)
        wait_until(
            lambda: _send(c, "bench", "ON") or ("bench", True, "MQTT") in desk.taken,
            "a command after the restart",
            timeout_s=20,
        )
        c.loop_stop()
    finally:
        sink.close()
        b.stop()


@given(st.binary(max_size=2 * MAX_PAYLOAD))
def test_any_payload_gives_a_switch_or_a_value_error(payload: bytes) -> None:
    try:
        on, by = parse_switch(payload)
    except (ValueError, UnicodeError):
        return
    assert isinstance(on, bool) and (by is None or (by.isprintable() and len(by) <= 64))
