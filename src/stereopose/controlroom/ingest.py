"""The control room's MQTT side: every site's event log outbox in, each event stored once,
the site's mark confirmed back (site.outbox's protocol, docs/mqtt.md#the-event-log-outbox),
and each site's state from its availability and its last message.

Subscriptions under the central broker's `<prefix>/+/`: `log/events` and `log/incidents`
(QoS 1), `available` (retained: `online`, or `offline` from a clean stop or the site's last
will), `log/heartbeat` (the site's last numbers, clock and summary every 10 s: what the
previous heartbeat announced and is still not stored is asked for again; the clock's offset
is kept, and beyond `clock_tolerance_s` raises a control-room incident) and `commands/done`
(a site's answer to an acknowledgement asked of it: `ask_ack` stores the command, the ingest
sends it on the site's `commands/ack` and again every `command_resend_s` until answered, so
an acknowledgement made while a site is cut off reaches it when the link is back). A site
shown offline raises a control-room incident, cleared when it is live again. paho's thread
only appends what comes to a bounded queue (at the bound a message is dropped and counted: its
site sends it again, since it is not confirmed); the ingest's own thread takes the queue every
`batch_s`, applies the protocol per site in arrival order (an event whose `prev` is at most
the site's mark is stored and raises the mark; one beyond it is a gap: a replay after the mark
is asked for, at most once per `replay_every_s`), stores each site's batch and its new mark in
one transaction, and then publishes the mark on the site's `log/confirmed` (retained). A site
whose last message is older than `offline_after_s` is shown offline.

What a peer sends is bounded before it is queued: the site names (those enrolled, read again
every ENROLMENT_EVERY_S, and `sites`: another name is refused, counted, raises one control-room
incident and never takes a place), a message's bytes per topic (`max_event_bytes` for
the outbox's events and incidents, `max_heartbeat_bytes`, small fixed ones for the rest), and
then its content: every number within what a store holds, strings, keys and lists of bounded
length, nesting at most MAX_DEPTH deep. An event id more than `ids_ahead` beyond the last id
the site's heartbeat announced is not taken as the site's mark (a broken or compromised site
would blind itself: every later real event would look like a resend): it is refused, counted
and raises a control-room incident; a later heartbeat that announces it asks for it again.
Every bad message is counted and logged at most once a minute a kind; none ends a thread.
A thread that dies anyway is restarted by `ensure_running` (the service's loop calls it), and
`health` says degraded while the ingest is down, or has stored nothing for STUCK_S while
events kept coming.
"""

from __future__ import annotations

import logging
import threading
import time
import uuid
from collections import deque

import paho.mqtt.client as paho
from paho.mqtt.reasoncodes import ReasonCode

from stereopose.config.service import ControlRoomConfig
from stereopose.controlroom.checks import heartbeat, incident_change, is_id, numbered
from stereopose.controlroom.checks import summary as beat_summary
from stereopose.controlroom.commands import AckCommands
from stereopose.controlroom.enrolment import Enrolment
from stereopose.controlroom.intake import QUEUE, Intake
from stereopose.controlroom.order import Order
from stereopose.controlroom.room import RoomIncidents
from stereopose.controlroom.site_pages import SitePages
from stereopose.controlroom.store import ControlStore, StoreError
from stereopose.io.sinks.mqtt_settings import (
    MqttSettings,
    loop_alive,
    make_client,
    restart_loop,
)
from stereopose.site.wire import (
    AVAILABLE,
    COMMAND_DONE,
    EVENTS,
    HEARTBEAT,
    INCIDENTS,
    receiver_subscriptions,
)
from stereopose.types import JsonDoc

__all__ = ["Ingest"]

logger = logging.getLogger(__name__)

CLOCK_WARN_S = 5.0  # a site's clock this far from ours is logged
PRUNE_EVERY_S = 3600.0  # how often the store's old rows are pruned
ENROLMENT_EVERY_S = 1.0  # how often the enrolled sites are read again
STUCK_S = 120.0  # events coming this long with none stored: the ingest is degraded
COUNTS = (
    "messages",
    "stored",
    "duplicates",
    "gaps",
    "replays",
    "malformed",
    "dropped",
    "store_errors",
    "behind",
    "incident_changes",
    "commands_sent",
    "commands_done",
    "room_incidents",
    "ingest_errors",
    "oversize",
    "refused_sites",
    "ahead",
    "restarts",
)  # figures()
STALL_S = 30.0  # the ingest's thread silent this long: down


class Ingest:
    """See the module. settings: the central broker ([mqtt]; its site is unused); store: the
    ControlStore; room: the [control_room] settings (None: the defaults)."""

    def __init__(
        self,
        settings: MqttSettings,
        store: ControlStore,
        room: ControlRoomConfig | None = None,
        *,
        batch_s: float = 0.1,
        replay_every_s: float = 2.0,
        queue_size: int = QUEUE,
    ) -> None:
        room = room if room is not None else ControlRoomConfig()
        self.settings, self.store = settings, store
        self.retention_days: float | None = room.retention_days  # None: kept for ever
        name, shared_group, sites = room.name, room.shared_group, room.sites
        offline_after_s, clock_tolerance_s = room.offline_after_s, room.clock_tolerance_s
        self._pruned_at = -PRUNE_EVERY_S  # the first step prunes
        self.clock_tolerance_s, self.name = float(clock_tolerance_s), name
        # several workers on one store: the broker gives each a share of the sites' messages
        self.shared = f"$share/{shared_group}/" if shared_group else ""
        self._summaries: dict[str, dict] = {}  # site -> its heartbeat's summary
        self._summaries_dirty: set[str] = set()
        self.offline_after_s, self.batch_s = float(offline_after_s), float(batch_s)
        self.prefix = settings.topic_prefix
        self._stop = threading.Event()
        self._seen: dict[str, float] = {}  # site -> its last message (Unix time)
        self._available: dict[str, str] = {}
        self._state: dict[str, str] = {}  # site -> the state last written to the store
        self.clock_offsets: dict[str, float] = {}  # site -> its clock minus ours (s)
        self._clock_warned: set[str] = set()
        self.counts: dict[str, int] = dict.fromkeys(COUNTS, 0)
        self._progress = time.monotonic()  # events stored, or none waiting to be
        self._stepped = time.monotonic()  # the ingest's thread last went round
        self._rate: deque[tuple[float, int]] = deque(maxlen=64)  # (time, messages) samples
        self.connected = False
        self.subscribed = False  # the broker confirmed the subscriptions of this connection
        self.client = self._make_client()
        self.room = RoomIncidents(store, self.counts, clock_tolerance_s)
        self.pages = SitePages(self.client, self.prefix)
        self.enrolment = Enrolment(store)
        self._enrolled_at = time.monotonic()
        self.intake = Intake(
            self.prefix,
            self.pages,
            self.counts,
            self.enrolment.names(),
            sites=sites,
            max_event_bytes=room.max_event_bytes,
            max_heartbeat_bytes=room.max_heartbeat_bytes,
            queue_size=queue_size,
        )
        self.order = Order(
            self.client,
            self.prefix,
            self.room,
            self._warn,
            shared=bool(self.shared),
            ids_ahead=room.ids_ahead,
            replay_every_s=replay_every_s,
        )
        self.commands = AckCommands(
            store,
            self.client,
            self.prefix,
            name,
            self.counts,
            resend_s=room.command_resend_s,
            shared=bool(self.shared),
        )
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

    def _on_subscribe(self, *_: object) -> None:
        self.subscribed = True

    def _on_connect(
        self, client: paho.Client, userdata: object, flags: object, reason: ReasonCode, *_: object
    ) -> None:
        if reason.is_failure:
            logger.error(
                "control room: the broker %s:%d refused the connection: %s",
                self.settings.host,
                self.settings.port,
                reason,
            )
            return
        self.connected = True
        share = self.shared
        client.subscribe(receiver_subscriptions(self.prefix, share))
        self.pages.follow_again(client)
        self.commands.send_all_again()
        logger.info("control room: connected to %s:%d", self.settings.host, self.settings.port)

    def _on_disconnect(
        self, client: paho.Client, userdata: object, flags: object, reason: ReasonCode, *_: object
    ) -> None:
        self.connected = self.subscribed = False
        if not self._stop.is_set():
            logger.warning(
                "control room: lost the broker %s:%d (%s); reconnecting",
                self.settings.host,
                self.settings.port,
                reason,
            )

    def _on_message(self, client: paho.Client, userdata: object, msg: paho.MQTTMessage) -> None:
        try:
            self._message(msg)
        except Exception as e:  # nothing one message holds may end paho's thread
            self.intake.count("malformed")
            self._warn(
                "message",
                f"control room: a message on {str(msg.topic)[:200]!r} "
                f"refused: {type(e).__name__}: {str(e)[:200]}",
            )

    def _message(self, msg: paho.MQTTMessage) -> None:
        self.intake.put(msg.topic, bytes(msg.payload))

    def _warn(self, kind: str, text: str) -> None:
        self.intake.warn(kind, text)

    def _note_refused(self) -> None:
        names, why = self.intake.refused()
        if names:
            shown = ", ".join(repr(n[:40]) for n in names)
            self.room.bad(
                self.name, "sites_refused", f"messages of unknown sites refused ({why}): {shown}"
            )

    # --- the ingest's thread -------------------------------------------------------------

    def _run(self) -> None:
        while not self._stop.wait(self.batch_s):
            self._stepped = time.monotonic()
            try:
                self._step()
            except Exception:  # a bug must not end the ingest: logged, the next batch
                self.counts["ingest_errors"] += 1
                logger.exception("control room: ingest failed; going on")
                # the marks back to what the store committed: a batch that failed confirms
                # nothing, and its sites send again what it held
                try:
                    self.order.reload()
                except StoreError as e:
                    logger.error("control room: %s", e)

    def _step(self) -> None:
        if time.monotonic() - self._enrolled_at >= ENROLMENT_EVERY_S:
            self._enrolled_at = time.monotonic()
            try:  # the store out: the sites enrolled before stay
                self.intake.enrol(self.enrolment.names())
            except StoreError as e:
                self._warn("enrolment", f"control room: {e}")
        batch = self.intake.take()
        per_site: dict[str, list[dict]] = {}
        changes: dict[str, list[dict]] = {}
        self._note_refused()
        self.room.clear_quiet()
        outbox = 0  # events and incident changes in this batch
        for site, what, payload, at in batch:
            self.counts["messages"] += 1
            self._seen[site] = max(self._seen.get(site, 0.0), at)
            if what == AVAILABLE:
                text = payload.decode("utf-8", "replace").strip()
                self._available[site] = text
                self._set_state(site, "live" if text == "online" else "offline")
                continue
            if what == HEARTBEAT:
                self._beat(site, payload, at)
                continue
            if what == COMMAND_DONE:
                self.commands.done(site, payload)
                continue
            incidents = what == INCIDENTS
            if what != EVENTS and not incidents:
                continue
            outbox += 1
            msg = numbered(payload, "seq" if incidents else "id")
            if (
                msg is None
                or msg.get("site", site) != site
                or (incidents and not incident_change(msg))
            ):
                self.counts["malformed"] += 1
                continue
            self.order.accept(site, incidents, msg, per_site, changes)
        # a worker's share: what came before what it holds may be in the store now
        self.order.release_held(per_site, changes)
        now = time.time()
        batch_sites = set(per_site) | set(changes)
        if batch_sites:
            try:  # one transaction for the whole batch
                new, written = self.store.put_batch(
                    {s: (v, self.order.marks[s]) for s, v in per_site.items()},
                    {s: (v, self.order.imarks[s]) for s, v in changes.items()},
                    now,
                )
                self.counts["stored"] += new
                self.counts["duplicates"] += sum(len(v) for v in per_site.values()) - new
                self.counts["incident_changes"] += written
                done = batch_sites
                if new or written:
                    self._progress = time.monotonic()
            except StoreError as e:  # then site by site: one site's fault stops only it
                logger.warning("control room: %s; storing site by site", e)
                done = self._put_each(per_site, changes, now)
            for site in done:
                if self._available.get(site) != "offline":
                    self._set_state(site, "live")
                self.order.confirm(site)
        if not outbox:
            self._progress = time.monotonic()  # nothing waited to be stored
        self._flush_summaries()
        self.commands.send()
        self.pages.leave_unwatched()
        self._prune()
        self._rate.append((now, self.counts["messages"]))
        for site, seen in list(self._seen.items()):
            if now - seen > self.offline_after_s and self._available.get(site) != "offline":
                self._available[site] = "offline"
                logger.warning("control room: site %s silent for %.0f s: offline", site, now - seen)
                self._set_state(site, "offline")

    def _put_each(self, per_site: dict, changes: dict, now: float) -> set[str]:
        """Each site's batch in its own transaction; the sites stored."""
        done = set()
        for site in set(per_site) | set(changes):
            try:
                if site in per_site:
                    events = per_site[site]
                    new = self.store.put_events(site, events, self.order.marks[site], now)
                    self.counts["stored"] += new
                    self.counts["duplicates"] += len(events) - new
                if site in changes:
                    self.counts["incident_changes"] += self.store.put_incidents(
                        site, changes[site], self.order.imarks[site], now
                    )
            except StoreError as e:  # not confirmed: the site sends them again
                self.counts["store_errors"] += 1
                self.order.reload()
                logger.error("control room: %s", e)
                continue
            done.add(site)
        return done

    def _prune(self) -> None:
        """Once an hour, what is older than `retention_days` out of the store (the marks
        stay: nothing pruned is asked for or stored again)."""
        now = time.monotonic()
        if self.retention_days is None or now - self._pruned_at < PRUNE_EVERY_S:
            return
        self._pruned_at = now
        try:
            gone = self.store.prune(time.time() - self.retention_days * 86400.0)
        except StoreError as e:
            self.counts["store_errors"] += 1
            logger.error("control room: %s", e)
            return
        if gone:
            logger.info(
                "control room: %d row(s) older than %g days pruned", gone, self.retention_days
            )

    def _beat(self, site: str, payload: bytes, at: float) -> None:
        """A site's heartbeat: its log's last id beyond the mark (the last events were lost
        and nothing later shows it) asks for a replay; its clock's offset is kept."""
        parsed = heartbeat(payload)
        if parsed is None:
            self.counts["malformed"] += 1
            return
        beat, last, sent = parsed
        self.clock_offsets[site] = offset = round(sent - at, 3)
        if abs(offset) > CLOCK_WARN_S and site not in self._clock_warned:
            self._clock_warned.add(site)
            logger.warning(
                "control room: site %s's clock is %+.1f s from this machine's", site, offset
            )
        self.room.clock(site, offset)
        summary = beat_summary(beat)
        if summary:
            summary["clock_offset_s"] = round(offset, 1)  # in the store: every worker's
        if summary and self._summaries.get(site) != summary:
            self._summaries[site] = summary
            self._summaries_dirty.add(site)
        if self._available.get(site) != "offline":
            self._set_state(site, "live")
        seq = beat.get("last_incident_seq")
        self.order.announce(site, last, seq if is_id(seq) else None)

    def _flush_summaries(self) -> None:
        if not self._summaries_dirty:
            return
        dirty = {s: self._summaries[s] for s in self._summaries_dirty}
        try:
            self.store.set_summaries(dirty)
        except StoreError as e:
            self.counts["store_errors"] += 1
            logger.error("control room: %s", e)
            return
        self._summaries_dirty.clear()

    # --- what the service asks ------------------------------------------------------------

    def known_sites(self) -> set[str]:
        """The sites with a plan (any thread; the store holds every site heard of)."""
        return self.pages.known_sites()

    def watch(self, site: str) -> dict:
        """The site's plan and people now (SitePages.watch)."""
        return self.pages.watch(site)

    def ask_ack(self, site: str, incident: int, by: str) -> int:
        """Ask `site` to acknowledge its `incident` as `by` (any thread); the command's id.
        StoreError when it cannot be stored."""
        return self.commands.ask(site, incident, by)

    def _set_state(self, site: str, state: str) -> None:
        """The site's state in the store, written only when it changes; offline raises a
        control-room incident, live clears it."""
        if self._state.get(site) != state and self.room.site_state(site, state):
            self._state[site] = state

    # --- figures, close ------------------------------------------------------------------

    def ensure_running(self) -> None:
        """The ingest's thread and paho's started again where one died (counted, logged);
        the service's loop calls this every half second."""
        if self._stop.is_set():
            return
        if not self._thread.is_alive():
            self.counts["restarts"] += 1
            logger.error("control room: the ingest's thread ended; started again")
            self._thread = threading.Thread(target=self._run, name="control-ingest", daemon=True)
            self._thread.start()
        if restart_loop(self.client):
            self.counts["restarts"] += 1
            logger.error("control room: the MQTT client's thread ended; started again")

    def health(self) -> tuple[bool, str]:
        """(ok, why not): down while a thread is, stuck while events come and none is stored."""
        now = time.monotonic()
        if not self._thread.is_alive() or now - self._stepped > STALL_S:
            return False, "the ingest is not running"
        if not loop_alive(self.client):
            return False, "the MQTT client is not running"
        if now - self._progress > STUCK_S:
            return False, f"events came and none was stored for {now - self._progress:.0f} s"
        return True, ""

    def figures(self) -> JsonDoc:
        f: dict[str, object] = dict(
            self.counts, queued=self.intake.queued(), enrolled=len(self.intake.admitted())
        )
        f.update(connected=self.connected, subscribed=self.subscribed)
        f["running"], f["trouble"] = self.health()
        if len(self._rate) >= 2:
            (t0, n0), (t1, n1) = self._rate[0], self._rate[-1]
            f["messages_per_s"] = round((n1 - n0) / (t1 - t0), 2) if t1 > t0 else 0.0
        else:
            f["messages_per_s"] = 0.0
        return f

    def lag_s(self) -> dict[str, float]:
        """Per site: seconds since its last message."""
        now = time.time()
        seen = dict(self._seen)  # the ingest thread's: copied at once
        return {s: round(now - t, 3) for s, t in seen.items()}

    def close(self) -> None:
        self._stop.set()
        self._thread.join(5.0)
        try:
            self.client.disconnect()
        finally:
            self.client.loop_stop()
