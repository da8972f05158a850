"""The control room's MQTT side: every site's event log outbox in, each event stored once,
the site's mark confirmed back (service.outbox's protocol, docs/mqtt.md#the-event-log-outbox),
and each site's state from its availability and its last message.

Subscriptions under the central broker's `<prefix>/+/`: `log/events` (QoS 1), `available`
(retained: `online`, or `offline` from a clean stop or the site's last will) and
`log/heartbeat` (the site's last id and clock every 10 s: what the previous heartbeat
announced and is still not stored is asked for again; the clock's offset is kept and logged
beyond CLOCK_WARN_S). paho's thread
only appends what comes to a bounded queue (at the bound a message is dropped and counted: its
site sends it again, since it is not confirmed); the ingest's own thread takes the queue every
`batch_s`, applies the protocol per site in arrival order (an event whose `prev` is at most
the site's mark is stored and raises the mark; one beyond it is a gap: a replay after the mark
is asked for, at most once per `replay_every_s`), stores each site's batch and its new mark in
one transaction, and then publishes the mark on the site's `log/confirmed` (retained). A site
whose last message is older than `offline_after_s` is shown offline.
"""

from __future__ import annotations

import json
import logging
import threading
import time
import uuid
from collections import deque
from typing import Any

import paho.mqtt.client as paho

from stereopose.controlroom.store import ControlStore, StoreError
from stereopose.io.sinks.mqtt_settings import MqttSettings, make_client, topic_name, topic_part

__all__ = ["Ingest"]

logger = logging.getLogger(__name__)

QUEUE = 100_000  # messages waiting for the ingest's thread at most
CLOCK_WARN_S = 5.0  # a site's clock this far from ours is logged
_MAX_ID = 2**63 - 1


class Ingest:
    """See the module. settings: the central broker ([mqtt]; its site is unused); store: the
    ControlStore."""

    def __init__(self, settings: MqttSettings, store: ControlStore, *,
                 offline_after_s: float = 90.0, batch_s: float = 0.1, replay_every_s: float = 2.0,
                 queue_size: int = QUEUE) -> None:  # fmt: skip
        self.settings, self.store = settings, store
        self.offline_after_s, self.batch_s = float(offline_after_s), float(batch_s)
        self.replay_every_s = float(replay_every_s)
        self.prefix = settings.topic_prefix
        self._queue: deque[tuple[str, str, bytes, float]] = deque()
        self.queue_size = int(queue_size)
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self.marks = store.marks()  # the ingest thread's only
        self._asked: dict[str, float] = {}  # site -> when a replay was last asked for
        self._seen: dict[str, float] = {}  # site -> its last message (Unix time)
        self._available: dict[str, str] = {}
        self._state: dict[str, str] = {}  # site -> the state last written to the store
        self.clock_offsets: dict[str, float] = {}  # site -> its clock minus ours (s)
        self._clock_warned: set[str] = set()
        self._announced: dict[str, int] = {}  # site -> the last id its last heartbeat gave
        self.counts = {"messages": 0, "stored": 0, "duplicates": 0, "gaps": 0, "replays": 0,
                       "malformed": 0, "dropped": 0, "store_errors": 0, "behind": 0}  # fmt: skip
        self._rate: deque[tuple[float, int]] = deque(maxlen=64)  # (time, messages) samples
        self.connected = False
        self.subscribed = False  # the broker confirmed the subscriptions of this connection
        self.client = self._make_client()
        self._thread = threading.Thread(target=self._run, name="control-ingest", daemon=True)
        self.client.connect_async(settings.host, settings.port, keepalive=settings.keepalive_s)
        self.client.loop_start()
        self._thread.start()

    def _make_client(self) -> paho.Client:
        s = self.settings
        c = make_client(s, f"stereopose-control-room-{uuid.uuid4().hex[:8]}")
        c.on_connect = self._on_connect
        c.on_disconnect = self._on_disconnect
        c.on_message = self._on_message
        c.on_subscribe = self._on_subscribe
        return c

    def _on_subscribe(self, client: Any, userdata: Any, mid: Any, reasons: Any,
                      props: Any) -> None:  # fmt: skip
        self.subscribed = True

    def _on_connect(self, client: Any, userdata: Any, flags: Any, reason: Any, props: Any) -> None:
        if reason.is_failure:
            logger.error("control room: the broker %s:%d refused the connection: %s",
                         self.settings.host, self.settings.port, reason)  # fmt: skip
            return
        self.connected = True
        client.subscribe([(f"{self.prefix}/+/log/events", 1), (f"{self.prefix}/+/available", 1),
                          (f"{self.prefix}/+/log/heartbeat", 0)])  # fmt: skip
        logger.info("control room: connected to %s:%d", self.settings.host, self.settings.port)

    def _on_disconnect(self, client: Any, userdata: Any, flags: Any, reason: Any,
                       props: Any) -> None:  # fmt: skip
        self.connected = self.subscribed = False
        if not self._stop.is_set():
            logger.warning("control room: lost the broker %s:%d (%s); reconnecting",
                           self.settings.host, self.settings.port, reason)  # fmt: skip

    def _on_message(self, client: Any, userdata: Any, msg: Any) -> None:
        rest = msg.topic[len(self.prefix) + 1 :].split("/")
        if not msg.topic.startswith(self.prefix + "/") or len(rest) < 2:
            return
        site, what = topic_name(rest[0]), "/".join(rest[1:])
        with self._lock:
            if len(self._queue) >= self.queue_size:
                self.counts["dropped"] += 1  # not confirmed: its site sends it again
                return
            self._queue.append((site, what, msg.payload, time.time()))

    # --- the ingest's thread -------------------------------------------------------------

    def _run(self) -> None:
        while not self._stop.wait(self.batch_s):
            try:
                self._step()
            except Exception:  # a bug must not end the ingest: logged, the next batch
                logger.exception("control room: ingest failed; going on")

    def _step(self) -> None:
        with self._lock:
            batch = list(self._queue)
            self._queue.clear()
        per_site: dict[str, list[dict]] = {}
        for site, what, payload, at in batch:
            self.counts["messages"] += 1
            self._seen[site] = max(self._seen.get(site, 0.0), at)
            if what == "available":
                text = payload.decode("utf-8", "replace").strip()
                self._available[site] = text
                self._set_state(site, "live" if text == "online" else "offline")
                continue
            if what == "log/heartbeat":
                self._beat(site, payload, at)
                continue
            event = _event(payload)
            if event is None or event.get("site", site) != site:
                self.counts["malformed"] += 1
                continue
            mark = self.marks.get(site, 0)
            if event["prev"] > mark:  # lost on the way: from the mark again
                self.counts["gaps"] += 1
                self._ask_replay(site, mark)
                continue
            per_site.setdefault(site, []).append(event)
            self.marks[site] = max(mark, event["id"])
        now = time.time()
        for site, events in per_site.items():
            try:
                new = self.store.put_events(site, events, self.marks[site], now)
            except StoreError as e:  # not confirmed: the site sends them again
                self.counts["store_errors"] += 1
                self.marks = self.store.marks()
                logger.error("control room: %s", e)
                continue
            self.counts["stored"] += new
            self.counts["duplicates"] += len(events) - new
            if self._available.get(site) != "offline":
                self._set_state(site, "live")
            self.client.publish(f"{self.prefix}/{topic_part(site)}/log/confirmed",
                                json.dumps({"events": self.marks[site]}), qos=1,
                                retain=True)  # fmt: skip
        self._rate.append((now, self.counts["messages"]))
        for site, seen in list(self._seen.items()):
            if now - seen > self.offline_after_s and self._available.get(site) != "offline":
                self._available[site] = "offline"
                logger.warning("control room: site %s silent for %.0f s: offline", site,
                               now - seen)  # fmt: skip
                self._set_state(site, "offline")

    def _beat(self, site: str, payload: bytes, at: float) -> None:
        """A site's heartbeat: its log's last id beyond the mark (the last events were lost
        and nothing later shows it) asks for a replay; its clock's offset is kept."""
        try:
            beat = json.loads(payload)
            last, sent = int(beat["last_id"]), float(beat["time"])
        except (ValueError, TypeError, KeyError, UnicodeDecodeError):
            self.counts["malformed"] += 1
            return
        self.clock_offsets[site] = round(sent - at, 3)
        if abs(sent - at) > CLOCK_WARN_S and site not in self._clock_warned:
            self._clock_warned.add(site)
            logger.warning("control room: site %s's clock is %+.1f s from this machine's",
                           site, sent - at)  # fmt: skip
        if self._available.get(site) != "offline":
            self._set_state(site, "live")
        # what the previous heartbeat announced is still not stored (not merely on its way)
        mark = self.marks.get(site, 0)
        if mark < self._announced.get(site, 0):
            self.counts["behind"] += 1
            self._ask_replay(site, mark)
        self._announced[site] = last

    def _set_state(self, site: str, state: str) -> None:
        """The site's state in the store, written only when it changes."""
        if self._state.get(site) == state:
            return
        try:
            self.store.set_site(site, state=state, last_seen=time.time())
        except StoreError as e:
            self.counts["store_errors"] += 1
            logger.error("control room: %s", e)
            return
        self._state[site] = state

    def _ask_replay(self, site: str, mark: int) -> None:
        now = time.monotonic()
        if now - self._asked.get(site, -1e9) < self.replay_every_s:
            return
        self._asked[site] = now
        self.counts["replays"] += 1
        self.client.publish(f"{self.prefix}/{topic_part(site)}/log/replay",
                            json.dumps({"after_id": mark}), qos=1)  # fmt: skip

    # --- figures, close ------------------------------------------------------------------

    def figures(self) -> dict:
        with self._lock:
            queued = len(self._queue)
        f = dict(self.counts, queued=queued, connected=self.connected, subscribed=self.subscribed)
        if len(self._rate) >= 2:
            (t0, n0), (t1, n1) = self._rate[0], self._rate[-1]
            f["messages_per_s"] = round((n1 - n0) / (t1 - t0), 2) if t1 > t0 else 0.0
        else:
            f["messages_per_s"] = 0.0
        return f

    def lag_s(self) -> dict[str, float]:
        """Per site: seconds since its last message."""
        now = time.time()
        return {s: round(now - t, 3) for s, t in self._seen.items()}

    def close(self) -> None:
        self._stop.set()
        self._thread.join(5.0)
        try:
            self.client.disconnect()
        finally:
            self.client.loop_stop()


def _event(payload: bytes) -> dict | None:
    """An outbox message with an int id and prev, or None."""
    try:
        e = json.loads(payload)
    except (ValueError, UnicodeDecodeError):
        return None
    if not isinstance(e, dict):
        return None
    for key in ("id", "prev"):
        v = e.get(key)
        if isinstance(v, bool) or not isinstance(v, int) or not 0 <= v <= _MAX_ID:
            return None
    return e
