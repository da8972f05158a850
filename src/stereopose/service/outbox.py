"""The event log as an outbox: every stored event published over MQTT with its log id, again
and again until a receiver (a control room) confirms it stored it.

Topics under ``<prefix>/<site>/log/`` (docs/mqtt.md#the-event-log-outbox):

- ``events`` (the site publishes, QoS 1): each event of the event log as ``/api/events``
  answers it, plus ``site`` and ``prev``: the id of the event published before it in this
  stream (0 at the log's start). (site, id) names an event everywhere; ids only grow, and an
  id is never given again.
- ``confirmed`` (a receiver publishes, retained, QoS 1): ``{"events": N}``, the highest id it
  has stored with nothing missing before it.
- ``replay`` (a receiver publishes, QoS 1): ``{"after_id": N}``, send every stored event
  after id N again.
- ``heartbeat`` (the site publishes every `heartbeat_s`, QoS 0): ``{"last_id": N, "time": T}``:
  the log's last id and the site's clock, so a receiver knows the site is there while nothing
  happens, sees the last events were lost when no later one shows it, and can tell how far
  the site's clock is from its own.

A receiver stores an event whose ``prev`` is at most its own mark (nothing is missing before
it; a duplicate is dropped by its id) and raises its mark to the event's id; an event whose
``prev`` is beyond its mark means some were lost on the way (a bridge that drops while cut,
a broker restarted without them): it asks for a replay after its mark.

The site's side (this module) keeps nothing per event: one cursor (the last id handed to the
broker), the receiver's confirmed mark, and counts. On each connection it starts again after
the confirmed mark (the retained message comes at once on subscribing; without one, after
the log's last id when the outbox started: a site without a control room does not send its
whole history), and when the mark has not reached the cursor for `resend_s` it starts again
after the mark. What it sends is read from the log (events.sqlite) in pages, at most
`inflight` messages handed to paho and not yet acknowledged by the broker, so a day's outage
is sent from the log, bounded by the log, never by memory.
"""

from __future__ import annotations

import json
import logging
import threading
import time
import uuid
from typing import Any

import paho.mqtt.client as paho

from stereopose.errors import ConfigError, StereoposeError
from stereopose.io.sinks.mqtt_settings import MqttSettings, make_client, topic_part

__all__ = ["LogOutbox"]

logger = logging.getLogger(__name__)

INFLIGHT = 50  # messages handed to paho and not yet acknowledged
PAGE = 200  # events read from the log at once at most
POLL_S = 0.25  # how often the log is read for new events when nothing wakes the thread
HEARTBEAT_S = 10.0  # how often the log's last id and the clock are published
_MAX_ID = 2**63 - 1


class LogOutbox:
    """See the module. settings: the site's broker ([mqtt]); log: a service.eventlog.EventLog
    (its `after(id, limit)` and `last_id()`); resend_s: how long the confirmed mark may stay
    behind what was sent before it is sent again (0: only on a new connection); start_after:
    the cursor without a confirmation (default: the log's last id now). `wake()` (after events
    were stored) makes the thread read the log at once."""

    def __init__(self, settings: MqttSettings, log: Any, *, resend_s: float = 30.0,
                 start_after: int | None = None, inflight: int = INFLIGHT,
                 poll_s: float = POLL_S, heartbeat_s: float = HEARTBEAT_S) -> None:  # fmt: skip
        self.heartbeat_s = float(heartbeat_s)
        self.settings, self.log = settings, log
        self.resend_s, self.inflight, self.poll_s = float(resend_s), int(inflight), float(poll_s)
        base = f"{settings.topic_prefix}/{topic_part(settings.site)}/log"
        self.topics = {k: f"{base}/{k}" for k in ("events", "confirmed", "replay", "heartbeat")}
        self.start_after = int(log.last_id() if start_after is None else start_after)
        self._lock = threading.Lock()
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._cursor = self.start_after  # the last id handed to paho
        self._confirmed: int | None = None  # the receiver's mark
        self._confirmed_at = time.monotonic()  # when the mark last moved (or was set)
        self._connected = False
        self._subscribed = False  # the broker confirmed this connection's subscriptions
        self._restart_at: int | None = None  # start again after this id (connect, replay)
        self._unacked: set[int] = set()  # paho message ids not yet acknowledged
        self._acked: set[int] = set()
        self.counts = {"published": 0, "resent": 0, "replays": 0, "malformed": 0,
                       "read_errors": 0}  # fmt: skip
        self._high = self._cursor  # the highest id ever sent: below it a send is a resend
        self._last_problem: str | None = None
        self.client = self._make_client()
        self._thread = threading.Thread(target=self._run, name="log-outbox", daemon=True)
        try:
            self.client.connect_async(settings.host, settings.port, keepalive=settings.keepalive_s)
        except (OSError, ValueError) as e:
            raise ConfigError(f"mqtt.host: cannot connect to {settings.host}:{settings.port}: "
                              f"{e}") from None  # fmt: skip
        self.client.loop_start()
        self._thread.start()

    def __repr__(self) -> str:
        return f"LogOutbox({self.settings.host}:{self.settings.port}, {self.topics['events']})"

    # --- paho's side ---------------------------------------------------------------------

    def _make_client(self) -> paho.Client:
        s = self.settings
        cid = f"stereopose-{topic_part(s.site)}-outbox-{uuid.uuid4().hex[:8]}"
        c = make_client(s, cid)
        c.max_inflight_messages_set(self.inflight)
        c.on_connect = self._on_connect
        c.on_disconnect = self._on_disconnect
        c.on_message = self._on_message
        c.on_publish = self._on_publish
        c.on_subscribe = self._on_subscribe
        return c

    def _on_subscribe(self, client: Any, userdata: Any, mid: Any, reasons: Any,
                      props: Any) -> None:  # fmt: skip
        with self._lock:
            self._subscribed = True

    def _on_connect(self, client: Any, userdata: Any, flags: Any, reason: Any, props: Any) -> None:
        if reason.is_failure:
            self._problem(logging.ERROR, f"the broker refused the connection: {reason}")
            return
        client.subscribe([(self.topics["confirmed"], 1), (self.topics["replay"], 1)])
        with self._lock:
            self._connected = True
            self._unacked.clear()
            self._acked.clear()
            # after the confirmed mark (a retained one may still come and move it back)
            self._restart_at = self._confirmed if self._confirmed is not None else None
            self._confirmed_at = time.monotonic()
        if self._last_problem is not None:
            logger.info("event outbox: connected to %s:%d again", self.settings.host,
                        self.settings.port)  # fmt: skip
        self._last_problem = None
        self._wake.set()

    def _on_disconnect(self, client: Any, userdata: Any, flags: Any, reason: Any,
                       props: Any) -> None:  # fmt: skip
        with self._lock:
            self._connected = self._subscribed = False
        if not self._stop.is_set():
            self._problem(logging.WARNING, f"the broker connection was lost ({reason}); "
                          "the events not confirmed are sent again when it is back")  # fmt: skip

    def _on_publish(self, client: Any, userdata: Any, mid: int, *rest: Any) -> None:
        with self._lock:
            self._acked.add(mid)
        self._wake.set()

    def _on_message(self, client: Any, userdata: Any, msg: Any) -> None:
        key = "after_id" if msg.topic == self.topics["replay"] else "events"
        value = _id_of(msg.payload, key)
        if value is None:
            with self._lock:
                self.counts["malformed"] += 1
            logger.warning("event outbox: ignored a malformed message on %s (expected "
                           '{"%s": <id>})', msg.topic, key)  # fmt: skip
            return
        with self._lock:
            if key == "after_id":
                self.counts["replays"] += 1
                self._restart_at = value if self._restart_at is None else min(
                    self._restart_at, value)  # fmt: skip
                logger.info("event outbox: a replay of the events after id %d was asked for",
                            value)  # fmt: skip
            else:
                first = self._confirmed is None
                if first or value != self._confirmed:
                    self._confirmed_at = time.monotonic()
                self._confirmed = value
                if first and value < self._cursor:  # the receiver is behind: from its mark
                    self._restart_at = value
        self._wake.set()

    def _problem(self, level: int, text: str) -> None:
        if text != self._last_problem:
            self._last_problem = text
            logger.log(level, "event outbox, MQTT %s:%d: %s", self.settings.host,
                       self.settings.port, text)  # fmt: skip

    # --- the sending thread --------------------------------------------------------------

    def _run(self) -> None:
        beat = 0.0
        while not self._stop.is_set():
            self._wake.wait(self.poll_s)
            self._wake.clear()
            try:
                self._send()
                if self._connected and time.monotonic() - beat >= self.heartbeat_s:
                    beat = time.monotonic()
                    self._heartbeat()
            except Exception:  # a bug must not end the outbox: logged, tried again
                logger.exception("event outbox: sending failed; trying again")
                self._stop.wait(1.0)

    def _send(self) -> None:
        with self._lock:
            if not self._connected:
                return
            self._unacked -= self._acked
            self._acked.clear()
            if self._restart_at is not None:
                self._cursor = self._restart_at
                self._restart_at = None
            elif (self.resend_s > 0 and self._confirmed is not None
                  and self._confirmed < self._cursor
                  and time.monotonic() - self._confirmed_at > self.resend_s):  # fmt: skip
                logger.info("event outbox: the receiver's mark stayed at %d (sent up to %d) "
                            "for %.0f s; sending again after it", self._confirmed,
                            self._cursor, self.resend_s)  # fmt: skip
                self._cursor = self._confirmed
                self._confirmed_at = time.monotonic()
            room = self.inflight - len(self._unacked)
            cursor = self._cursor
        while room > 0:
            try:
                rows = self.log.after(cursor, limit=min(PAGE, room))
            except StereoposeError as e:  # the log locked or being recovered: next time
                with self._lock:
                    self.counts["read_errors"] += 1
                self._problem(logging.WARNING, f"cannot read the event log: {e}")
                return
            if not rows:
                return
            for row in rows:
                payload = json.dumps({"site": self.settings.site, "prev": cursor, **row},
                                     separators=(",", ":"), default=str)  # fmt: skip
                info = self.client.publish(self.topics["events"], payload, qos=1)
                if info.rc != paho.MQTT_ERR_SUCCESS:  # the link went: from here next time
                    return
                with self._lock:
                    if self._restart_at is not None:  # a replay or a reconnect meanwhile
                        return
                    self._unacked.add(info.mid)
                    self._cursor = cursor = int(row["id"])
                    self.counts["resent" if cursor <= self._high else "published"] += 1
                    self._high = max(self._high, cursor)
                room -= 1

    def _heartbeat(self) -> None:
        try:
            last = int(self.log.last_id())
        except StereoposeError as e:
            self._problem(logging.WARNING, f"cannot read the event log: {e}")
            return
        body = json.dumps({"last_id": last, "time": round(time.time(), 3)})
        self.client.publish(self.topics["heartbeat"], body, qos=0)

    def wake(self) -> None:
        self._wake.set()

    # --- figures, close ------------------------------------------------------------------

    def figures(self) -> dict:
        """Published and resent events, replays asked, the cursor, the receiver's mark, and
        the lag (events sent but not confirmed: the cursor's id minus the mark)."""
        with self._lock:
            f = dict(self.counts)
            f.update(
                cursor=self._cursor,
                confirmed=self._confirmed,
                connected=self._connected,
                subscribed=self._subscribed,
                unacknowledged=len(self._unacked - self._acked),
                lag=None if self._confirmed is None else max(0, self._high - self._confirmed),
            )
        return f  # fmt: skip

    def close(self, timeout_s: float = 5.0) -> None:
        """Send what the log holds beyond the cursor, waiting for the broker's acknowledgement
        at most `timeout_s` (a service closes this after its last events are stored), then
        disconnect; what is left is sent by the next run, after the confirmed mark."""
        self._stop.set()
        self._wake.set()
        self._thread.join(timeout_s)
        deadline = time.monotonic() + timeout_s
        try:
            while time.monotonic() < deadline and self._connected:
                self._send()
                with self._lock:
                    waiting = len(self._unacked - self._acked)
                    cursor = self._cursor
                if not waiting and cursor >= self.log.last_id():
                    break
                time.sleep(0.02)
        except StereoposeError as e:  # the log unreadable at the end: the next run sends it
            logger.warning("event outbox: cannot send the last events: %s", e)
        try:
            self.client.disconnect()
        finally:
            self.client.loop_stop()


def _id_of(payload: bytes, key: str) -> int | None:
    """The id under `key` of a JSON object payload, or None when malformed."""
    try:
        obj = json.loads(payload)
    except (ValueError, UnicodeDecodeError):
        return None
    value = obj.get(key) if isinstance(obj, dict) else None
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= _MAX_ID:
        return None
    return value
