"""A detection node's link to the site's broker (nodes.node): its messages out, in a bounded
queue of QoS 0 sent on a thread of its own while connected (a message older than STALE_S when
its turn comes is dropped and counted: the fusion service would take it as late), its
retained health with a last will saying offline; and in, the fusion service's holds
(nodes.hold), subscribed on every connection.
"""

from __future__ import annotations

import contextlib
import logging
import threading
import time
import uuid
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from stereopose.io.sinks.mqtt_settings import MqttSettings, make_client
from stereopose.nodes.wire import Topics, health_message

if TYPE_CHECKING:
    import paho.mqtt.client as mqtt
    from paho.mqtt.properties import Properties
    from paho.mqtt.reasoncodes import ReasonCode

logger = logging.getLogger(__name__)

STALE_S = 2.0
QUEUE_SIZE = 256


@dataclass
class _Counts:
    published: int = 0
    dropped: int = 0  # the queue full, or stale when their turn came
    pictures: int = 0
    bytes: int = 0


class Publisher:
    """The node's link to the broker: a bounded queue of QoS 0 messages sent on a thread of
    its own while connected, the retained health with its last will."""

    def __init__(
        self,
        settings: MqttSettings,
        topics: Topics,
        node: str,
        queue_size: int = QUEUE_SIZE,
        on_hold: Callable[[bytes], object] | None = None,
    ) -> None:
        self.settings, self.topics, self.node = settings, topics, node
        self.counts = _Counts()
        self.connected = False
        self._queue: deque[tuple[str, bytes, float]] = deque()
        self._size = queue_size
        self._lock = threading.Condition()
        self._stop = False
        self._problem: str | None = None
        cid = f"stereopose-node-{uuid.uuid4().hex[:8]}"
        c = make_client(settings, cid)
        c.will_set(topics.node(node), health_message(node, "offline"), qos=1, retain=True)
        c.max_queued_messages_set(queue_size)
        c.on_connect = self._on_connect
        c.on_disconnect = self._on_disconnect
        c.on_connect_fail = self._on_connect_fail
        self.on_hold = on_hold  # each hold message from the fusion service (nodes.hold)
        if on_hold is not None:
            c.message_callback_add(topics.hold, self._on_hold)
        self.client = c
        self.on_connect: Any = None
        c.connect_async(settings.host, settings.port, keepalive=settings.keepalive_s)
        c.loop_start()
        self._thread = threading.Thread(target=self._send, name="node-publish", daemon=True)
        self._thread.start()

    def _on_connect(
        self,
        client: mqtt.Client,
        userdata: object,
        flags: mqtt.ConnectFlags,
        reason: ReasonCode,
        props: Properties | None,
    ) -> None:
        if reason.is_failure:
            self._say(logging.ERROR, f"the broker refused the connection: {reason}; retrying")
            return
        with self._lock:
            self.connected = True
            self._lock.notify_all()
        if self.on_hold is not None:  # on every connection: a broker restarted forgets it
            client.subscribe(self.topics.hold, qos=0)
        if self._problem is not None:
            logger.info("MQTT %s:%d: connected", self.settings.host, self.settings.port)
        self._problem = None
        if self.on_connect is not None:
            self.on_connect()

    def _on_hold(self, client: mqtt.Client, userdata: object, msg: mqtt.MQTTMessage) -> None:
        take = self.on_hold
        if take is None:
            return
        try:
            take(bytes(msg.payload))
        except Exception:  # whatever a peer sent: counted by the watch, never the thread's end
            logger.exception("node: a hold message could not be taken")

    def _on_disconnect(
        self,
        client: mqtt.Client,
        userdata: object,
        flags: mqtt.DisconnectFlags,
        reason: ReasonCode,
        props: Properties | None,
    ) -> None:
        with self._lock:
            was, self.connected = self.connected, False
        if was and not self._stop:
            self._say(logging.WARNING, "connection lost; retrying")

    def _on_connect_fail(self, client: mqtt.Client, userdata: object) -> None:
        self._say(logging.WARNING, "broker unreachable; retrying")

    def _say(self, level: int, text: str) -> None:
        if text != self._problem:
            self._problem = text
            logger.log(level, "MQTT %s:%d: %s", self.settings.host, self.settings.port, text)

    def put(self, topic: str, payload: bytes) -> None:
        with self._lock:
            if len(self._queue) >= self._size:
                self._queue.popleft()
                self.counts.dropped += 1
            self._queue.append((topic, payload, time.monotonic()))
            self._lock.notify_all()

    def queued(self) -> int:
        return len(self._queue)

    def _send(self) -> None:
        while True:
            with self._lock:
                while not self._stop and not (self.connected and self._queue):
                    self._lock.wait(0.5)
                if self._stop and (not self.connected or not self._queue):
                    return
                topic, payload, at = self._queue.popleft()
            if time.monotonic() - at > STALE_S:
                self.counts.dropped += 1
                continue
            info = self.client.publish(topic, payload, qos=0)
            if info.rc == 0:
                self.counts.published += 1
                self.counts.bytes += len(payload)
            else:
                self.counts.dropped += 1

    def health(self, payload: bytes) -> None:
        """The node's health, retained (QoS 1); nothing while the broker is away."""
        if self.connected:
            self.client.publish(self.topics.node(self.node), payload, qos=1, retain=True)

    def close(self, timeout_s: float = 3.0) -> None:
        """Say offline (retained), drain what is queued within the bound, disconnect."""
        with self._lock:
            self._stop = True
            self._lock.notify_all()
        self._thread.join(timeout_s)
        if self.connected:
            info = self.client.publish(
                self.topics.node(self.node),
                health_message(self.node, "offline"),
                qos=1,
                retain=True,
            )
            with contextlib.suppress(RuntimeError, ValueError):  # the link went meanwhile
                info.wait_for_publish(timeout_s)
        self.client.disconnect()
        self.client.loop_stop()
