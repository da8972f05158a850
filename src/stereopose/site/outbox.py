"""The event log as an outbox: every stored event and every change of an incident published
over MQTT with its log number, again and again until a receiver (a control room) confirms it
stored it; and the receiver's acknowledgements of incidents taken in.

The protocol (its topics, who sends each, the bodies, how a receiver keeps its marks) is
described and built in site.wire, shared with the control room's ingest.

The site's side (this module) keeps nothing per event: per stream one cursor (the last number
handed to the broker), the receiver's confirmed mark, and counts. On each connection it starts
again after the confirmed mark (the retained message comes at once on subscribing; without
one, after the log's last number when the outbox started: a site without a control room does
not send its whole history), and when the mark has not reached the cursor for `resend_s` it
starts again after the mark. What it sends is read from the log (events.sqlite) in pages, at
most `inflight` messages handed to paho and not yet acknowledged by the broker, so a day's
outage is sent from the log, bounded by the log, never by memory.
"""

from __future__ import annotations

import json
import logging
import threading
import time
import uuid
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import paho.mqtt.client as paho
from paho.mqtt.reasoncodes import ReasonCode

from stereopose.alarms.incident import IncidentRecord
from stereopose.errors import ConfigError, StereoposeError
from stereopose.io.sinks.health import OutputHealth
from stereopose.io.sinks.mqtt_settings import (
    MqttSettings,
    loop_alive,
    make_client,
    restart_loop,
    topic_part,
)
from stereopose.site.desk import remote_ack
from stereopose.site.wire import COMMAND_KEYS, id_of, parse_ack, site_topics

__all__ = ["LogOutbox"]

logger = logging.getLogger(__name__)

INFLIGHT = 50  # messages handed to paho and not yet acknowledged
PAGE = 200  # events read from the log at once at most
POLL_S = 0.25  # how often the log is read for new events when nothing wakes the thread
CLOSE_RESEND_S = 1.0  # at the close, a receiver's mark behind this long: sent again
HEARTBEAT_S = 10.0  # how often the log's last id and the clock are published


@dataclass(eq=False)
class _Stream:
    """One numbered stream of the log: its topic, the confirmation's and the replay's keys,
    and its reader (`after(n, limit)` -> rows carrying `key`, `last()` -> the last number)."""

    name: str
    topic: str
    key: str
    replay_key: str
    after: Callable[[int, int], list[dict]]
    last: Callable[[], int]
    confirmed: int | None = None  # the receiver's mark
    restart_at: int | None = None  # start again after this number (connect, replay)
    published: int = 0
    resent: int = 0

    def __post_init__(self) -> None:
        self.cursor = self.high = int(self.last())  # the last handed to paho; the highest sent
        self.confirmed_at = time.monotonic()  # when the mark last moved (or was set)

    def figures(self) -> dict:
        lag = None if self.confirmed is None else max(0, self.high - self.confirmed)
        return {
            "published": self.published,
            "resent": self.resent,
            "cursor": self.cursor,
            "confirmed": self.confirmed,
            "lag": lag,
        }


@dataclass(frozen=True)
class OutboxPace:
    """resend_s: how long the confirmed mark may stay behind what was sent before it is sent
    again (0: only on a new connection); inflight: messages handed to paho and not yet
    acknowledged by the broker, at most."""

    resend_s: float = 30.0
    inflight: int = INFLIGHT
    poll_s: float = POLL_S  # the log read at least this often
    heartbeat_s: float = HEARTBEAT_S


class LogOutbox:
    """See the module. settings: the site's broker ([mqtt]); log: a site.eventlog.EventLog
    (its `after(id, limit)` and `last_id()`; with `incident_changes_after(seq, limit)` and
    `last_incident_change()` the incidents' stream too); pace: see OutboxPace; start_after:
    the events' cursor without a confirmation (default: the log's last id now).
    `wake()` (after events were stored) makes the thread read the log at once.
    acknowledger(incident_id, by): the incident book's acknowledge, the commands' way in (->
    the incident's record; a BookNotRunningError, or None: answered "unavailable");
    summary(): a dict added to each heartbeat."""

    def __init__(
        self,
        settings: MqttSettings,
        log: Any,
        pace: OutboxPace = OutboxPace(),
        *,
        start_after: int | None = None,
        acknowledger: Callable[[int, str], IncidentRecord] | None = None,
        summary: Callable[[], dict] | None = None,
        plan: dict | None = None,
    ) -> None:
        self.settings, self.log, self.pace = settings, log, pace
        self.acknowledger, self.summary, self.plan = acknowledger, summary, plan
        self.topics = site_topics(settings.topic_prefix, settings.site)  # site.wire
        self.streams = [
            _Stream(
                "events",
                self.topics["events"],
                "id",
                "after_id",
                lambda n, k: log.after(n, limit=k),
                log.last_id,
            )
        ]
        if start_after is not None:
            self.streams[0].cursor = self.streams[0].high = int(start_after)
        if hasattr(log, "incident_changes_after"):
            self.streams.append(
                _Stream(
                    "incidents",
                    self.topics["incidents"],
                    "seq",
                    "incidents_after",
                    log.incident_changes_after,
                    log.last_incident_change,
                )
            )
        self.start_after = self.streams[0].cursor
        self._lock = threading.Lock()
        self._wake = threading.Event()
        self._stop = threading.Event()
        # _subscribed: the broker confirmed this connection's subscriptions
        self._connected = self._subscribed = False
        self._unacked: set[int] = set()  # paho message ids not yet acknowledged
        self._acked: set[int] = set()
        self.counts = {"replays": 0, "malformed": 0, "read_errors": 0, "commands": 0, "restarts": 0}
        self._warned_at = -60.0  # when a refused message was last logged
        self._last_problem: str | None = None
        self.client = self._make_client()
        self._thread = threading.Thread(target=self._run, name="log-outbox", daemon=True)
        try:
            self.client.connect_async(settings.host, settings.port, keepalive=settings.keepalive_s)
        except (OSError, ValueError) as e:
            raise ConfigError(
                f"mqtt.host: cannot connect to {settings.host}:{settings.port}: {e}"
            ) from None
        self.client.loop_start()
        self._thread.start()

    def __repr__(self) -> str:
        return f"LogOutbox({self.settings.host}:{self.settings.port}, {self.topics['events']})"

    # --- paho's side ---------------------------------------------------------------------

    def _make_client(self) -> paho.Client:
        s = self.settings
        cid = f"stereopose-{topic_part(s.site)}-outbox-{uuid.uuid4().hex[:8]}"
        c = make_client(s, cid)
        c.max_inflight_messages_set(self.pace.inflight)
        c.on_connect = self._on_connect
        c.on_disconnect = self._on_disconnect
        c.on_message = self._on_message
        c.on_publish = self._on_publish
        c.on_subscribe = self._on_subscribe
        return c

    def _on_subscribe(self, *_: object) -> None:
        with self._lock:
            self._subscribed = True

    def _on_connect(
        self, client: paho.Client, userdata: object, flags: object, reason: ReasonCode, *_: object
    ) -> None:
        if reason.is_failure:
            self._problem(logging.ERROR, f"the broker refused the connection: {reason}")
            return
        client.subscribe(
            [(self.topics["confirmed"], 1), (self.topics["replay"], 1), (self.topics["ack"], 1)]
        )
        if self.plan is not None:  # retained: a control room's page of this site
            client.publish(self.topics["plan"], json.dumps(self.plan), qos=1, retain=True)
        with self._lock:
            self._connected = True
            self._unacked.clear()
            self._acked.clear()
            for st in self.streams:  # after the confirmed mark (a retained one may move it)
                st.restart_at = st.confirmed
                st.confirmed_at = time.monotonic()
        if self._last_problem is not None:
            logger.info(
                "event outbox: connected to %s:%d again", self.settings.host, self.settings.port
            )
        self._last_problem = None
        self._wake.set()

    def _on_disconnect(
        self, client: paho.Client, userdata: object, flags: object, reason: ReasonCode, *_: object
    ) -> None:
        with self._lock:
            self._connected = self._subscribed = False
        if not self._stop.is_set():
            self._problem(
                logging.WARNING,
                f"the broker connection was lost ({reason}); "
                "the events not confirmed are sent again when it is back",
            )

    def _on_publish(self, client: paho.Client, userdata: object, mid: int, *rest: object) -> None:
        with self._lock:
            self._acked.add(mid)
        self._wake.set()

    def _on_message(self, client: paho.Client, userdata: object, msg: paho.MQTTMessage) -> None:
        try:
            self._message(msg)
        except Exception as e:  # nothing one message holds may end paho's thread
            with self._lock:
                self.counts["malformed"] += 1
            now = time.monotonic()
            if now - self._warned_at >= 60.0:  # logged at most once a minute
                self._warned_at = now
                logger.warning(
                    "event outbox: a message on %s refused: %s: %s",
                    str(msg.topic)[:200],
                    type(e).__name__,
                    str(e)[:200],
                )

    def _message(self, msg: paho.MQTTMessage) -> None:
        payload = bytes(msg.payload)
        if msg.topic == self.topics["ack"]:
            self._command(payload)
            return
        replay = msg.topic == self.topics["replay"]
        keys = {
            st.name: id_of(payload, st.replay_key if replay else st.name) for st in self.streams
        }
        if all(v is None for v in keys.values()):
            with self._lock:
                self.counts["malformed"] += 1
            want = "after_id" if replay else "events"
            logger.warning(
                'event outbox: ignored a malformed message on %s (expected {"%s": <id>})',
                msg.topic,
                want,
            )
            return
        with self._lock:
            for st in self.streams:
                value = keys[st.name]
                if value is None:
                    continue
                if replay:
                    self.counts["replays"] += 1
                    st.restart_at = value if st.restart_at is None else min(st.restart_at, value)
                    logger.info(
                        "event outbox: a replay of the %s after %d was asked for", st.name, value
                    )
                    continue
                first = st.confirmed is None
                if first or value != st.confirmed:
                    st.confirmed_at = time.monotonic()
                st.confirmed = value
                if first and value < st.cursor:  # the receiver is behind: from its mark
                    st.restart_at = value
        self._wake.set()

    def _command(self, payload: bytes) -> None:
        """An acknowledgement asked by the receiver (paho's thread: the book's act is short)."""
        cmd = parse_ack(payload)
        if cmd is None:
            with self._lock:
                self.counts["malformed"] += 1
            logger.warning(
                "event outbox: ignored a malformed command on %s (expected %s)",
                self.topics["ack"],
                COMMAND_KEYS,
            )
            return
        with self._lock:
            self.counts["commands"] += 1
        command, incident, by = cmd
        result = remote_ack(self.acknowledger, incident, by)
        if result == "acknowledged":
            logger.info("incident %d acknowledged by %s", incident, by)
        body = json.dumps({"command": command, "incident": incident, "result": result})
        self.client.publish(self.topics["done"], body, qos=1)

    def _problem(self, level: int, text: str) -> None:
        if text != self._last_problem:
            self._last_problem = text
            logger.log(
                level, "event outbox, MQTT %s:%d: %s", self.settings.host, self.settings.port, text
            )

    # --- the sending thread --------------------------------------------------------------

    def _run(self) -> None:
        beat = 0.0
        while not self._stop.is_set():
            self._wake.wait(self.pace.poll_s)
            self._wake.clear()
            try:
                self._send()
                if self._connected and time.monotonic() - beat >= self.pace.heartbeat_s:
                    beat = time.monotonic()
                    self._heartbeat()
            except Exception:  # a bug must not end the outbox: logged, tried again
                logger.exception("event outbox: sending failed; trying again")
                self._stop.wait(1.0)

    def _send(self) -> None:
        for st in self.streams:
            if not self._send_stream(st):
                return

    def _send_stream(self, st: _Stream) -> bool:
        """What `st` has beyond its cursor, while there is room; False when the link or the
        log stopped it (the next streams wait for the next round)."""
        with self._lock:
            if not self._connected:
                return False
            self._unacked -= self._acked
            self._acked.clear()
            if st.restart_at is not None:
                st.cursor = st.restart_at
                st.restart_at = None
            elif (
                self.pace.resend_s > 0
                and st.confirmed is not None
                and st.confirmed < st.cursor
                and time.monotonic() - st.confirmed_at > self.pace.resend_s
            ):
                logger.info(
                    "event outbox: the receiver's mark of the %s stayed at %d (sent up "
                    "to %d) for %.0f s; sending again after it",
                    st.name,
                    st.confirmed,
                    st.cursor,
                    self.pace.resend_s,
                )
                st.cursor = st.confirmed
                st.confirmed_at = time.monotonic()
            room = self.pace.inflight - len(self._unacked)
            cursor = st.cursor
        while room > 0:
            try:
                rows = st.after(cursor, min(PAGE, room))
            except StereoposeError as e:  # the log locked or being recovered: next time
                with self._lock:
                    self.counts["read_errors"] += 1
                self._problem(logging.WARNING, f"cannot read the event log: {e}")
                return False
            if not rows:
                return True
            for row in rows:
                payload = json.dumps(
                    {"site": self.settings.site, "prev": cursor, **row},
                    separators=(",", ":"),
                    default=str,
                )
                info = self.client.publish(st.topic, payload, qos=1)
                if info.rc != paho.MQTT_ERR_SUCCESS:  # the link went: from here next time
                    return False
                with self._lock:
                    if st.restart_at is not None:  # a replay or a reconnect meanwhile
                        return False
                    self._unacked.add(info.mid)
                    st.cursor = cursor = int(row[st.key])
                    if cursor <= st.high:
                        st.resent += 1
                    else:
                        st.published += 1
                    st.high = max(st.high, cursor)
                room -= 1
        return False

    def _heartbeat(self) -> None:
        try:
            body: dict[str, object] = {"last_id": int(self.log.last_id())}
            if len(self.streams) > 1:
                body["last_incident_seq"] = int(self.streams[1].last())
        except StereoposeError as e:
            self._problem(logging.WARNING, f"cannot read the event log: {e}")
            return
        body["time"] = round(time.time(), 3)
        if self.summary is not None:
            try:
                body.update({k: v for k, v in self.summary().items() if k not in body})
            except Exception:  # a failing summary must not stop the heartbeat
                logger.exception("event outbox: the site's summary failed")
        self.client.publish(self.topics["heartbeat"], json.dumps(body, default=str), qos=0)

    def wake(self) -> None:
        self._wake.set()

    # --- figures, close ------------------------------------------------------------------

    def figures(self) -> dict:
        """Published and resent events, replays asked, the cursor, the receiver's mark, and
        the lag (events sent but not confirmed: the cursor's id minus the mark); the same of
        the incidents' stream under `incidents`."""
        with self._lock:
            ev = self.streams[0].figures()
            lag = ev.pop("lag")
            f = {**self.counts, **ev, "connected": self._connected, "subscribed": self._subscribed}
            f.update(unacknowledged=len(self._unacked - self._acked), lag=lag)
            for st in self.streams[1:]:
                f[st.name] = st.figures()
        return f

    def ensure_running(self) -> None:
        """The sending thread and paho's started again where one died (counted, logged); the
        service's watchdog calls this every half second."""
        if self._stop.is_set():
            return
        if not self._thread.is_alive():
            self.counts["restarts"] += 1
            logger.error("event outbox: the sending thread ended; started again")
            self._thread = threading.Thread(target=self._run, name="log-outbox", daemon=True)
            self._thread.start()
        if restart_loop(self.client):
            self.counts["restarts"] += 1
            logger.error("event outbox: the MQTT client's thread ended; started again")

    def health(self) -> OutputHealth:
        """Not ok while a thread is down (the broker's link is the MQTT output's health);
        waiting: the events sent and not confirmed."""
        with self._lock:
            lag = self.streams[0].figures()["lag"] or 0
        if not self._thread.is_alive() and not self._stop.is_set():
            return OutputHealth(False, lag, "the event outbox's sending thread is not running")
        if not loop_alive(self.client):
            return OutputHealth(False, lag, "the event outbox's MQTT client is not running")
        return OutputHealth(True, lag)

    def _confirmed_or_resent(self) -> bool:
        """At the close, all sent: whether each confirmed stream is confirmed to its cursor (a
        mark behind for CLOSE_RESEND_S: sent again after it)."""
        now = time.monotonic()
        with self._lock:
            behind = [s for s in self.streams if s.confirmed is not None and s.confirmed < s.cursor]
            for st in behind:
                if now - st.confirmed_at > CLOSE_RESEND_S:
                    st.restart_at, st.confirmed_at = st.confirmed, now
        return not behind

    def close(self, timeout_s: float = 5.0) -> None:
        """Send what the log holds beyond the cursors, waiting for the broker's
        acknowledgement and, where a receiver has confirmed before, for its mark to reach the
        cursor (sent again after the mark when it stays behind for CLOSE_RESEND_S) at most
        `timeout_s` in all (a service closes this after its last events are stored), then
        disconnect; what is left is sent by the next run, after the confirmed marks."""
        self._stop.set()
        self._wake.set()
        self._thread.join(timeout_s)
        deadline = time.monotonic() + timeout_s
        try:
            while time.monotonic() < deadline and self._connected:
                self._send()
                with self._lock:
                    waiting = len(self._unacked - self._acked)
                    cursors = [st.cursor for st in self.streams]
                sent = not waiting and all(
                    c >= st.last() for c, st in zip(cursors, self.streams, strict=True)
                )
                if sent and self._confirmed_or_resent():
                    break
                time.sleep(0.02)
        except StereoposeError as e:  # the log unreadable at the end: the next run sends it
            logger.warning("event outbox: cannot send the last events: %s", e)
        try:
            self.client.disconnect()
        finally:
            self.client.loop_stop()
