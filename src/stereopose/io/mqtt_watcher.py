"""A zone's breakers and earthing switches read over MQTT: a subscriber on the site's broker
(`[mqtt]`) to each point's topic (retained states come at once), onto a PowerBoard
(zones.power_state); paho's thread reconnects with backoff, and a lost connection makes the
points unknown. A payload is a reading: its JSON value ({"value": ...} or {"state": ...} as
bridges publish), or its text; anything else is refused and counted.
"""

from __future__ import annotations

import json
import uuid
from collections.abc import MutableMapping
from typing import TYPE_CHECKING, Any

from stereopose.io.sinks.mqtt_settings import MqttSettings
from stereopose.zones.power import MqttPoint, reading
from stereopose.zones.power_state import PowerBoard

if TYPE_CHECKING:
    import paho.mqtt.client as mqtt
    from paho.mqtt.properties import Properties
    from paho.mqtt.reasoncodes import ReasonCode

__all__ = ["MqttWatcher"]

MAX_PAYLOAD = 4096


def _payload(raw: bytes | bytearray) -> Any:
    """An MQTT payload as a reading: its JSON value, or its text; None when unreadable."""
    if len(raw) > MAX_PAYLOAD:
        return None
    try:
        text = raw.decode("utf-8").strip()
    except UnicodeDecodeError:
        return None
    try:
        value = json.loads(text)
    except (ValueError, RecursionError):
        return text or None
    if isinstance(value, dict):  # {"value": ...} as many bridges publish
        value = value.get("value", value.get("state"))
    if value is None or isinstance(value, (list, dict)):
        return None
    return reading(value)


class MqttWatcher:
    """A subscriber on the site's broker (paho's thread reconnects with backoff)."""

    def __init__(
        self,
        settings: MqttSettings,
        points: list[MqttPoint],
        board: PowerBoard,
        figures: MutableMapping[str, int],
    ) -> None:
        from stereopose.io.sinks.mqtt_settings import make_client  # paho, loaded here

        self.settings, self.board, self.figures = settings, board, figures
        self.topics = {p.topic: p.label for p in points}
        self.client = make_client(settings, f"stereopose-state-{uuid.uuid4().hex[:8]}")
        self.client.on_connect = self._on_connect
        self.client.on_disconnect = self._on_disconnect
        self.client.on_message = self._on_message

    def __repr__(self) -> str:
        return f"MQTT subscriber of {self.settings.host}:{self.settings.port}"

    def start(self) -> None:
        self.client.connect_async(self.settings.host, self.settings.port, keepalive=30)
        self.client.loop_start()

    def stop(self) -> None:
        self.client.disconnect()
        self.client.loop_stop()

    def _on_connect(
        self,
        client: mqtt.Client,
        userdata: object,
        flags: mqtt.ConnectFlags,
        reason: ReasonCode,
        props: Properties | None,
    ) -> None:
        if reason.is_failure:
            self.board.lost(list(self.topics.values()), f"MQTT broker refused: {reason}")
            return
        for topic in self.topics:
            client.subscribe(topic, qos=1)

    def _on_disconnect(
        self,
        client: mqtt.Client,
        userdata: object,
        flags: mqtt.DisconnectFlags,
        reason: ReasonCode,
        props: Properties | None,
    ) -> None:
        self.figures["mqtt_link_lost"] += 1
        self.board.lost(list(self.topics.values()), "MQTT broker link lost")

    def _on_message(self, client: mqtt.Client, userdata: object, message: mqtt.MQTTMessage) -> None:
        label = self.topics.get(message.topic)
        value = _payload(message.payload) if label is not None else None
        if label is None or value is None:
            self.figures["mqtt_refused"] += 1
            if label is not None:
                self.board.set(label, None, False, "an unreadable payload")
            return
        self.figures["mqtt_received"] += 1
        self.board.set(label, value, True)
