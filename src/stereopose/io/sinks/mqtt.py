"""Alarms out over MQTT, the convention of camera-event systems (Frigate, Home Assistant).

Topics under ``<prefix>/<site>/`` (see docs/mqtt.md):

- ``events``: each zone event as the events JSON lines write it (io.records), QoS 1.
- ``zones/<zone>``: who is inside each zone, retained, QoS 1; derived from the zone's enter and
  exit events; every known zone is published (empty at first) on each connect; a zone with a
  state source also says `power` (live, dead, unknown) and `power_source`.
- ``people``: the current people (id, floor position, heading), at most ``people_hz`` per second
  of the frames' own clock, QoS 0.
- ``available``: ``online`` retained on connect; ``offline`` retained at a clean close and as
  the last will, so a crash or a lost link reads ``offline``.
- ``site``: the running site's version and zones, retained, QoS 1 (`set_site`: at the start
  and at each change; a removed zone's retained state is cleared).
- ``warnings``: what warns on site now (onsite.warner: each hazard with its speakers and
  signals), retained, QoS 1 (`set_warnings`, each time it changes).

The frame loop never waits on the network: `write` only appends to bounded queues; a sender
thread hands messages to paho (whose network loop runs on its own thread and reconnects with
backoff) while connected, a few at a time. When the queue bound is hit the oldest people update
is dropped first, the oldest event only when no people update is left; drops are counted and
logged once per burst. Zone states are not queued: only each zone's latest state is kept, and
it is sent again on every connect (the broker may have lost it in a restart).
"""

from __future__ import annotations

import contextlib
import logging
import threading
import time
import uuid
from collections import deque
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import paho.mqtt.client as paho
from paho.mqtt.reasoncodes import ReasonCode

from stereopose.alarms import Change
from stereopose.io.records import event_record, people_record
from stereopose.io.sinks.base import ClosesOnce, FrameResult
from stereopose.io.sinks.health import OutputHealth
from stereopose.io.sinks.mqtt_commands import ZoneCommands
from stereopose.io.sinks.mqtt_retained import Message, Retained, dumps
from stereopose.io.sinks.mqtt_settings import (
    MqttSettings,
    make_client,
    stop_loop,
    topic_name,
    topic_part,
)
from stereopose.types import Event

__all__ = ["MqttSettings", "MqttSink", "people_record", "topic_name", "topic_part"]

logger = logging.getLogger(__name__)

KINDS = ("events", "zones", "people", "incidents")
ONLINE, OFFLINE = "online", "offline"
INFLIGHT = 20  # messages handed to paho and not yet acknowledged (paho's own default window)


@dataclass
class _Counts:
    published: dict[str, int] = field(default_factory=lambda: dict.fromkeys(KINDS, 0))
    dropped: dict[str, int] = field(default_factory=lambda: dict.fromkeys(KINDS, 0))
    failed: dict[str, int] = field(default_factory=lambda: dict.fromkeys(KINDS, 0))
    refused: int = 0  # connections the broker refused (bad login, not authorised)
    burst: int = 0  # dropped since the queue last had room


class MqttSink(ClosesOnce):
    """A sink of the frame loop publishing events, zone occupancy and people over MQTT; an
    alarm output (io.sinks.health.AlarmOutput).

    settings: the broker and topics. zone_names: the site's zones, published empty at start
    (zones met only in events are added as they come). `figures()` gives, per kind (events,
    zones, people), how many were published (acknowledged for QoS 1), are still queued, were
    dropped (queue full) or failed (the client refused the message).
    """

    stage = "write"

    def __init__(
        self,
        settings: MqttSettings,
        zone_names: Iterable[str] = (),
        switch: Callable[[str, bool, str], None] | None = None,
    ) -> None:
        self.settings = s = settings
        self.commands = None if switch is None else ZoneCommands(s, switch)
        base = f"{s.topic_prefix}/{topic_part(s.site)}"
        kinds = ("events", "people", "available", "incidents", "site", "warnings")
        self.topics = {k: f"{base}/{k}" for k in kinds}
        self._lock = threading.Lock()
        self._wake = threading.Event()
        self._stop = False
        self._queues: dict[str, deque[tuple[int, Message]]] = {
            "events": deque(),
            "people": deque(),
            "incidents": deque(),
        }
        self._seq = 0
        self._retained = Retained(self.topics, f"{base}/zones/", zone_names)
        self._inflight: deque[tuple[str, paho.MQTTMessageInfo]] = deque()
        # message ids paho says are sent (QoS 0) or acknowledged (QoS 1): a message published
        # while the link was down keeps that error in its info even once paho has resent it
        self._acked: set[int] = set()
        self._connected = self._announce = self._resync = False
        self._last_problem: str | None = None
        self._people_t: float | None = None
        self._people_empty = True
        self._counts = _Counts()
        self._client = self._make_client()
        self._sender = threading.Thread(target=self._send_loop, name="mqtt-send", daemon=True)
        self._sender.start()
        self._client.connect_async(s.host, s.port, keepalive=s.keepalive_s)
        self._client.loop_start()

    def __repr__(self) -> str:
        return f"MqttSink({self.settings!r})"

    # --- the frame loop's side: never touches the network ---

    def write(self, frame: FrameResult) -> None:
        self.write_events(frame.events)
        self._write_people(frame)

    def write_events(self, events: Sequence[Event]) -> None:
        """Queue events and update the occupancy of their zones."""
        if not events:
            return
        with self._lock:
            for e in events:
                self._put(Message("events", self.topics["events"], dumps(event_record(e)), 1))
                self._retained.occupy(e)
        self._wake.set()

    def write_changes(self, changes: Sequence[Change]) -> None:
        """Queue incident changes (alarms.Change) for `<prefix>/<site>/incidents`, QoS 1: each
        Change.to_dict(), in order with the events."""
        if not changes:
            return
        with self._lock:
            for c in changes:
                body = dumps(c.to_dict())
                self._put(Message("incidents", self.topics["incidents"], body, 1))
        self._wake.set()

    def set_site(self, version: str, zones: Sequence[str], t: float) -> None:
        """The running site (at the start, and each change at wall time t): `site` retained
        with its version and zones; a new zone's state published empty, a removed one's
        cleared (an empty retained message)."""
        with self._lock:
            self._retained.set_site(version, zones, t)
        self._wake.set()

    def set_warnings(self, doc: dict) -> None:
        """What warns on site now (onsite.warner: each hazard with its speakers and
        signals), retained on `<prefix>/<site>/warnings`: a newer one replaces one not sent."""
        with self._lock:
            self._retained.set_warnings(doc)
        self._wake.set()

    def _write_people(self, frame: FrameResult) -> None:
        hz = self.settings.people_hz
        if hz <= 0:
            return
        t, last = frame.t, self._people_t
        # by the frames' clock: the same frames always give the same updates; 1 us of slack
        # for t = frame / fps landing a rounding error short of the period
        if last is not None and last <= t < last + 1.0 / hz - 1e-6:
            return
        empty = len(frame.people3d) == 0
        if empty and self._people_empty:
            return  # nobody now and nobody in the last update: nothing new to say
        self._people_t, self._people_empty = t, empty
        payload = dumps(people_record(frame.people3d, t, frame.postures))
        with self._lock:
            self._put(Message("people", self.topics["people"], payload, 0))
        self._wake.set()

    def _put(self, msg: Message) -> None:
        """Append under the lock; at the bound drop the oldest people update, else the oldest
        event."""
        queues = self._queues
        if sum(len(q) for q in queues.values()) >= self.settings.queue_size:
            victim = next(queues[k] for k in ("people", "events", "incidents") if queues[k])
            kind = victim.popleft()[1].kind
            self._counts.dropped[kind] += 1
            if self._counts.burst == 0:
                logger.warning(
                    "MQTT %s:%d: %d messages waiting, the bound: dropping the oldest "
                    "(people updates first) until the broker takes them",
                    self.settings.host,
                    self.settings.port,
                    self.settings.queue_size,
                )
            self._counts.burst += 1
        self._seq += 1
        queues[msg.kind].append((self._seq, msg))

    # --- the sender thread: hands messages to paho while connected ---

    def _send_loop(self) -> None:
        while True:
            self._wake.wait(0.2)
            self._wake.clear()
            while (msg := self._next()) is not None:
                self._publish(msg)
            if self._stop:
                return

    def _next(self) -> Message | None:
        """The next message to hand over, or None (not connected, window full, nothing)."""
        with self._lock:
            self._sweep()
            if not self._connected or len(self._inflight) >= INFLIGHT:
                return None
            if self._resync:
                if self._inflight:
                    return None  # paho resends these first: later messages keep their order
                self._resync = False
            if self._announce:
                self._announce = False
                return Message("available", self.topics["available"], ONLINE, 1, retain=True)
            retained = self._retained.next()
            if retained is not None:
                return retained
            heads = [q for q in self._queues.values() if q]
            if not heads:
                self._end_burst()
                return None
            return min(heads, key=lambda q: q[0][0]).popleft()[1]

    def _publish(self, msg: Message) -> None:
        try:
            info = self._client.publish(msg.topic, msg.payload, qos=msg.qos, retain=msg.retain)
        except Exception as e:  # paho refuses it (too large, bad topic): the sender goes on
            info, problem = None, f"{type(e).__name__}: {e}"
        else:
            ok = (paho.MQTT_ERR_SUCCESS, paho.MQTT_ERR_NO_CONN)  # NO_CONN: paho resends it
            problem = None if info.rc in ok else paho.error_string(info.rc)
        with self._lock:
            if problem is None and info is not None:
                self._inflight.append((msg.kind, info))
            elif msg.kind in KINDS:
                self._counts.failed[msg.kind] += 1
                logger.error("MQTT: cannot publish to %s: %s", msg.topic, problem)

    def _done(self, info: paho.MQTTMessageInfo) -> bool:
        """Whether paho has sent (QoS 0) or the broker acknowledged (QoS 1) the message."""
        if info.mid in self._acked:
            return True
        try:
            return info.is_published()
        except (RuntimeError, ValueError):  # published while disconnected: resent later
            return False

    def _sweep(self) -> None:
        """Count what the broker has acknowledged (QoS 1) or paho has sent (QoS 0)."""
        while self._inflight and self._done(self._inflight[0][1]):
            kind, info = self._inflight.popleft()
            self._acked.discard(info.mid)
            if kind in KINDS:
                self._counts.published[kind] += 1
        # later ones may be done before an earlier one (QoS 0 after a pending QoS 1)
        if any(self._done(info) for _, info in self._inflight):
            rest = deque()
            for kind, info in self._inflight:
                if self._done(info):
                    self._acked.discard(info.mid)
                    if kind in KINDS:
                        self._counts.published[kind] += 1
                else:
                    rest.append((kind, info))
            self._inflight = rest
        if len(self._acked) > 4 * INFLIGHT:  # ids of messages not followed here (none known)
            self._acked.clear()

    def _end_burst(self) -> None:
        if self._counts.burst:
            logger.warning(
                "MQTT: %d messages were dropped while the queue was full", self._counts.burst
            )
            self._counts.burst = 0

    # --- paho's network thread ---

    def _make_client(self) -> paho.Client:
        s = self.settings
        client_id = s.client_id or f"stereopose-{topic_part(s.site)}-{uuid.uuid4().hex[:8]}"
        c = make_client(s, client_id)
        c.will_set(self.topics["available"], OFFLINE, qos=1, retain=True)
        c.max_inflight_messages_set(INFLIGHT)
        c.on_connect = self._on_connect
        c.on_connect_fail = self._on_connect_fail
        c.on_disconnect = self._on_disconnect
        c.on_publish = self._on_publish
        return c

    def _on_publish(self, client: paho.Client, userdata: object, mid: int, *rest: object) -> None:
        self._acked.add(mid)  # a set's add is atomic: no lock on paho's thread
        self._wake.set()

    def _problem(self, level: int, text: str) -> None:
        """Log a connection problem once, not on every retry."""
        if text != self._last_problem:
            self._last_problem = text
            logger.log(level, "MQTT %s:%d: %s", self.settings.host, self.settings.port, text)

    def _on_connect(
        self, client: paho.Client, userdata: object, flags: object, reason: ReasonCode, *_: object
    ) -> None:
        if reason.is_failure:
            with self._lock:
                self._counts.refused += 1
            self._problem(logging.ERROR, f"the broker refused the connection: {reason}; retrying")
            return
        with self._lock:
            self._connected = self._announce = True
            self._resync = bool(self._inflight)
            self._retained.connected()  # the broker may have lost its retained states
            waiting = sum(len(q) for q in self._queues.values())
        if self._last_problem is not None:
            st = self.settings
            logger.info("MQTT %s:%d: connected; %d messages waiting", st.host, st.port, waiting)
        self._last_problem = None
        self._wake.set()

    def _on_connect_fail(self, client: paho.Client, userdata: object) -> None:
        tls = self.settings.tls
        why = "broker unreachable or TLS handshake failed" if tls else "broker unreachable"
        self._problem(logging.WARNING, f"{why}; queueing and retrying")

    def _on_disconnect(
        self, client: paho.Client, userdata: object, flags: object, reason: ReasonCode, *_: object
    ) -> None:
        with self._lock:
            was_up, self._connected = self._connected, False
        # after a refused login the link was never up: that refusal is the news, not this
        if was_up and not self._stop:
            self._problem(logging.WARNING, "connection lost; queueing and retrying")

    # --- close ---

    def figures(self) -> dict[str, dict[str, int]]:
        """Per kind: published, queued (waiting or not yet acknowledged), dropped, failed."""
        with self._lock:
            self._sweep()
            c = self._counts
            queued = {k: len(self._queues.get(k, ())) for k in KINDS}
            for kind, _ in self._inflight:
                if kind in queued:
                    queued[kind] += 1
            queued["zones"] += self._retained.pending()
            return {
                k: {
                    "published": c.published[k],
                    "queued": queued[k],
                    "dropped": c.dropped[k],
                    "failed": c.failed[k],
                }
                for k in KINDS
            }

    # --- as an alarm output (io.sinks.health.AlarmOutput) ---

    output_name = "mqtt"

    @property
    def label(self) -> str:
        return f"MQTT {self.settings.host}:{self.settings.port}"

    def queued(self) -> int:
        return sum(v["queued"] for v in self.figures().values())

    @property
    def dropped(self) -> int:
        return sum(v["dropped"] for v in self.figures().values())

    def health(self) -> OutputHealth:
        """Not ok while not connected (the broker unreachable, the link lost, the login
        refused); waiting: the messages not yet acknowledged, of every kind."""
        waiting = sum(v["queued"] for v in self.figures().values())
        with self._lock:
            connected, refused = self._connected, self._counts.refused
        if connected:
            return OutputHealth(True, waiting)
        problem = self._last_problem or ""
        if problem.startswith("the broker refused"):
            why = f"the broker refused the connection ({refused} time(s))"
        elif problem.startswith("connection lost"):
            why = "connection to the broker lost"
        elif problem:
            why = "broker unreachable"
        else:
            why = "not connected to the broker yet"
        return OutputHealth(False, waiting, why)

    @property
    def refused(self) -> int:
        """Connections the broker refused (a bad login, not authorised)."""
        return self._counts.refused

    def _drained(self) -> bool:
        return all(v["queued"] == 0 for v in self.figures().values())

    def _close(self) -> list[Path]:
        deadline = time.monotonic() + self.settings.close_timeout_s
        while not self._drained() and time.monotonic() < deadline:
            self._wake.set()
            time.sleep(0.02)
        self._stop = True
        self._wake.set()
        self._sender.join(timeout=1.0)
        if self._connected:
            info = self._client.publish(self.topics["available"], OFFLINE, qos=1, retain=True)
            # the link may go meanwhile (paho raises); the will says offline then
            with contextlib.suppress(RuntimeError, ValueError):
                info.wait_for_publish(timeout=max(0.5, deadline - time.monotonic()))
        self._client.disconnect()
        stop_loop(self._client, self.settings.close_timeout_s)
        if self.commands is not None:
            self.commands.close()
        self._report()
        return []

    def _report(self) -> None:
        counts = self.figures()
        text = "; ".join(
            f"{k} " + ", ".join(f"{n} {w}" for w, n in v.items()) for k, v in counts.items()
        )
        lost = any(v["queued"] or v["dropped"] or v["failed"] for v in counts.values())
        level, st = logging.WARNING if lost else logging.INFO, self.settings
        logger.log(level, "MQTT %s:%d closed: %s", st.host, st.port, text)
