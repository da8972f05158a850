"""Zones switched off and on over MQTT (`[mqtt] commands = true`, docs/mqtt.md):
``<prefix>/<site>/zones/<zone>/enabled`` with ``OFF`` / ``ON`` (or ``false`` / ``true``, ``0`` /
``1``), or a JSON object ``{"enabled": false, "by": "control desk"}`` naming who switched it.

Each command is handed to `switch(zone, on, by)` (site.site_desk.SiteDesk.switch_zone: taken at
the next step, an event saying who did it); `by` is "MQTT", or "MQTT: <by>" with the payload's
name. A command for a zone the site does not have, or one that cannot be read (too long, not
one of the forms above, a name that is not printable), is refused: counted and logged at most
once a minute, never raised into paho's thread. Its own connection to the broker (the alarm
outputs' link never waits for a command), subscribed again at each connect. Who may switch a
zone is the broker's to say: its ACL grants the topic.
"""

from __future__ import annotations

import json
import logging
import threading
import time
import uuid
from collections.abc import Callable

import paho.mqtt.client as paho
from paho.mqtt.reasoncodes import ReasonCode

from stereopose.errors import StereoposeError
from stereopose.io.sinks.mqtt_settings import (
    MqttSettings,
    make_client,
    stop_loop,
    topic_name,
    topic_part,
)

__all__ = ["ZoneCommands", "parse_switch"]

logger = logging.getLogger(__name__)

MAX_PAYLOAD = 1024  # bytes of a command at most
MAX_BY = 64  # characters of the payload's `by` at most
WORDS = {"on": True, "true": True, "1": True, "off": False, "false": False, "0": False}


def parse_switch(payload: bytes) -> tuple[bool, str | None]:
    """(on, by) of a command's payload; ValueError naming what is wrong."""
    if len(payload) > MAX_PAYLOAD:
        raise ValueError(f"{len(payload)} bytes, at most {MAX_PAYLOAD}")
    text = payload.decode("utf-8").strip()
    if text.lower() in WORDS:
        return WORDS[text.lower()], None
    doc = json.loads(text)
    if not isinstance(doc, dict) or not isinstance(doc.get("enabled"), bool):
        raise ValueError('expected ON, OFF or {"enabled": true|false, "by": "..."}')
    by = doc.get("by")
    if by is not None and not (isinstance(by, str) and 0 < len(by) <= MAX_BY and by.isprintable()):
        raise ValueError(f"by: 1 to {MAX_BY} printable characters")
    return doc["enabled"], by


class ZoneCommands:
    """See the module. settings: the site's broker ([mqtt]); switch(zone, on, by): raises
    StereoposeError for a zone it does not have. `close()` once."""

    def __init__(self, settings: MqttSettings, switch: Callable[[str, bool, str], None]) -> None:
        self.settings, self.switch = settings, switch
        base = f"{settings.topic_prefix}/{topic_part(settings.site)}/zones/"
        self._base, self.topic = base, base + "+/enabled"
        self.counts = {"taken": 0, "refused": 0}
        self._lock = threading.Lock()
        self._warned_at = -60.0
        cid = f"stereopose-{topic_part(settings.site)}-commands-{uuid.uuid4().hex[:8]}"
        self.client = make_client(settings, cid)
        self.client.on_connect = self._on_connect
        self.client.on_message = self._on_message
        self.client.connect_async(settings.host, settings.port, keepalive=settings.keepalive_s)
        self.client.loop_start()

    def _on_connect(
        self, client: paho.Client, userdata: object, flags: object, reason: ReasonCode, *_: object
    ) -> None:
        if not reason.is_failure:
            client.subscribe(self.topic, qos=1)

    def _on_message(self, client: paho.Client, userdata: object, msg: paho.MQTTMessage) -> None:
        try:
            zone = topic_name(msg.topic[len(self._base) :].rsplit("/", 1)[0])
            on, by = parse_switch(bytes(msg.payload))
            self.switch(zone, on, "MQTT" if by is None else f"MQTT: {by}")
        except (ValueError, UnicodeError, StereoposeError) as e:
            self._refuse(msg.topic, str(e))
        except Exception as e:  # nothing one message holds may end paho's thread
            logger.exception("MQTT commands: %s failed", str(msg.topic)[:200])
            self._refuse(msg.topic, type(e).__name__)
        else:
            with self._lock:
                self.counts["taken"] += 1

    def _refuse(self, topic: str, why: str) -> None:
        with self._lock:
            self.counts["refused"] += 1
            now = time.monotonic()
            if now - self._warned_at < 60.0:
                return
            self._warned_at = now
        logger.warning("MQTT commands: refused on %s: %s", topic[:200], why[:200])

    def close(self) -> None:
        self.client.disconnect()
        stop_loop(self.client, self.settings.close_timeout_s)
