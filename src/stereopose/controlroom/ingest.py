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

What a peer sends is bounded before it is queued: the site names (`sites`, a list of those
that may report, or at most `max_sites` names: a message from another is refused, counted,
and raises one control-room incident), a message's bytes per topic (`max_event_bytes` for
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

import json
import logging
import math
import threading
import time
import uuid
from collections import deque
from typing import Any

import paho.mqtt.client as paho

from stereopose.controlroom.store import ControlStore, StoreError
from stereopose.io.sinks.mqtt_settings import (
    MqttSettings,
    loop_alive,
    make_client,
    restart_loop,
)
from stereopose.site.wire import (
    AVAILABLE,
    COMMAND_ACK,
    COMMAND_DONE,
    CONFIRMED,
    EVENTS,
    HEARTBEAT,
    INCIDENTS,
    PEOPLE,
    PLAN,
    REPLAY,
    ack_body,
    confirmed_body,
    receiver_subscriptions,
    replay_body,
    site_topic,
    split_topic,
)

__all__ = ["Ingest"]

logger = logging.getLogger(__name__)

QUEUE = 100_000  # messages waiting for the ingest's thread at most
CLOCK_WARN_S = 5.0  # a site's clock this far from ours is logged
HOLD_S = 3.0  # a worker holds a message this long for the one before it (another worker's)
MAX_HELD = 10_000  # messages held per site and stream at most
WATCH_S = 15.0  # a site's people are followed this long after its page last looked
MAX_PLAN_BYTES = 1 << 20  # a plan or people message larger than this is ignored
MAX_SITES = 100_000  # plans kept at most
PRUNE_EVERY_S = 3600.0  # how often the store's old rows are pruned
_MAX_ID = 2**63 - 1
MAX_DEPTH = 8  # an outbox message nests no deeper (an event, an incident's record)
WARN_EVERY_S = 60.0  # a kind of bad message logged at most this often
MAX_TEXT = 4096  # characters of one string in an outbox message at most
MAX_ITEMS = 256  # keys of one object, items of one list, at most
# bytes of a message on these topics at most (the outbox's and heartbeat's come from settings)
SMALL_TOPICS = {AVAILABLE: 64, COMMAND_DONE: 1024}
SUMMARY_COUNTS = ("cameras", "cameras_up", "people")  # a heartbeat's summary: these, status
MAX_STATUS = 32  # characters of a heartbeat's status at most
MAX_COUNT = 1_000_000  # a heartbeat's cameras, cameras_up, people at most
STUCK_S = 120.0  # events coming this long with none stored: the ingest is degraded
QUIET_S = 600.0  # a control-room incident about bad messages clears after this long without
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
    ControlStore."""

    def __init__(
        self,
        settings: MqttSettings,
        store: ControlStore,
        *,
        offline_after_s: float = 90.0,
        batch_s: float = 0.1,
        replay_every_s: float = 2.0,
        queue_size: int = QUEUE,
        clock_tolerance_s: float = 5.0,
        name: str = "control-room",
        command_resend_s: float = 5.0,
        shared_group: str = "",
        retention_days: float | None = None,
        sites: tuple[str, ...] | list[str] = (),
        max_sites: int = 1000,
        max_event_bytes: int = 65_536,
        max_heartbeat_bytes: int = 8192,
        ids_ahead: int = 100_000,
    ) -> None:
        self.settings, self.store = settings, store
        self.allowed_sites = frozenset(sites)  # empty: any name, up to max_sites
        self.max_sites, self.ids_ahead = int(max_sites), int(ids_ahead)
        self.max_bytes = {
            **SMALL_TOPICS,
            EVENTS: int(max_event_bytes),
            INCIDENTS: int(max_event_bytes),
            HEARTBEAT: int(max_heartbeat_bytes),
            PLAN: MAX_PLAN_BYTES,
            PEOPLE: MAX_PLAN_BYTES,
        }
        # the site names admitted (those in the store, then each new one up to max_sites)
        self._sites: set[str] = {r.site for r in store.sites()}
        self._refused: list[str] = []  # site names refused since the ingest last looked
        # (site, kind) -> when a bad message of that kind last came (the incident's clearing)
        self._bad_at: dict[tuple[str, str], float] = {}
        self._ahead: dict[tuple[str, bool], int] = {}  # the highest id refused as ahead
        self.retention_days = retention_days  # None: kept for ever
        self._pruned_at = -PRUNE_EVERY_S  # the first step prunes
        self.clock_tolerance_s, self.name = float(clock_tolerance_s), name
        # several workers on one store: the broker gives each a share of the sites' messages
        self.shared = f"$share/{shared_group}/" if shared_group else ""
        # (site, incidents?) -> prev -> (message, held since): a worker's out-of-order share
        self._held: dict[tuple[str, bool], dict[int, tuple[dict, float]]] = {}
        self._pending_checked = time.monotonic()
        self.command_resend_s = float(command_resend_s)
        self.imarks = store.incident_marks()  # the ingest thread's only
        self._announced_i: dict[str, int] = {}
        self._summaries: dict[str, dict] = {}  # site -> its heartbeat's summary
        self._summaries_dirty: set[str] = set()
        # command -> [site, incident, by, last sent (monotonic; 0: not yet)]
        self._commands: dict[int, list] = {
            c: [s, i, b, 0.0] for c, s, i, b in store.pending_commands()
        }
        self._clock_off: set[str] = set()  # sites with an active clock incident
        self._plans: dict[str, dict] = {}  # site -> its retained plan (zones, console_url)
        self._people: dict[str, tuple[float, dict]] = {}  # watched site -> (when, latest)
        self._watched: dict[str, float] = {}  # site -> when its page last looked (monotonic)
        self.offline_after_s, self.batch_s = float(offline_after_s), float(batch_s)
        self.replay_every_s = float(replay_every_s)
        self.prefix = settings.topic_prefix
        self._queue: deque[tuple[str, str, bytes, float]] = deque()
        self.queue_size = int(queue_size)
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self.marks = store.marks()  # the ingest thread's only
        self._asked: dict[tuple[str, bool], float] = {}  # (site, incidents) -> last replay
        self._seen: dict[str, float] = {}  # site -> its last message (Unix time)
        self._available: dict[str, str] = {}
        self._state: dict[str, str] = {}  # site -> the state last written to the store
        self.clock_offsets: dict[str, float] = {}  # site -> its clock minus ours (s)
        self._clock_warned: set[str] = set()
        self._announced: dict[str, int] = {}  # site -> the last id its last heartbeat gave
        self.counts = dict.fromkeys(COUNTS, 0)
        self._progress = time.monotonic()  # events stored, or none waiting to be
        self._stepped = time.monotonic()  # the ingest's thread last went round
        self._warned_at: dict[str, float] = {}  # kind of bad message -> when last logged
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

    def _on_subscribe(self, client: Any, userdata: Any, mid: Any, reasons: Any, props: Any) -> None:
        self.subscribed = True

    def _on_connect(self, client: Any, userdata: Any, flags: Any, reason: Any, props: Any) -> None:
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
        with self._lock:
            watched = list(self._watched)
        for site in watched:  # a new connection: the pages being looked at follow again
            client.subscribe(site_topic(self.prefix, site, PEOPLE), 0)
        with self._lock:  # the unanswered acknowledgements go again at once
            for c in self._commands.values():
                c[3] = 0.0
        logger.info("control room: connected to %s:%d", self.settings.host, self.settings.port)

    def _on_disconnect(
        self, client: Any, userdata: Any, flags: Any, reason: Any, props: Any
    ) -> None:
        self.connected = self.subscribed = False
        if not self._stop.is_set():
            logger.warning(
                "control room: lost the broker %s:%d (%s); reconnecting",
                self.settings.host,
                self.settings.port,
                reason,
            )

    def _on_message(self, client: Any, userdata: Any, msg: Any) -> None:
        try:
            self._message(msg)
        except Exception as e:  # nothing one message holds may end paho's thread
            with self._lock:
                self.counts["malformed"] += 1
            self._warn(
                "message",
                f"control room: a message on {str(msg.topic)[:200]!r} "
                f"refused: {type(e).__name__}: {str(e)[:200]}",
            )

    def _warn(self, kind: str, text: str) -> None:
        """Log `text` unless a message of this kind was logged within the last minute."""
        now = time.monotonic()
        if now - self._warned_at.get(kind, -WARN_EVERY_S) >= WARN_EVERY_S:
            self._warned_at[kind] = now
            logger.warning("%s", text)

    def _message(self, msg: Any) -> None:
        parts = split_topic(self.prefix, msg.topic)
        if parts is None:
            return
        site, what = parts
        limit = self.max_bytes.get(what)
        if limit is None:  # not a topic of the protocol (nor an answer to one)
            return
        if len(msg.payload) > limit:
            with self._lock:
                self.counts["oversize"] += 1
            self._warn(
                "oversize",
                f"control room: a {len(msg.payload)}-byte message on "
                f"{str(msg.topic)[:200]!r} refused (at most {limit})",
            )
            return
        if not self._admit(site):
            return
        if what in (PLAN, PEOPLE):  # the latest only, kept at once (bounded: one a site)
            self._latest(site, what, msg.payload)
            return
        with self._lock:
            if len(self._queue) >= self.queue_size:
                self.counts["dropped"] += 1  # not confirmed: its site sends it again
                return
            self._queue.append((site, what, msg.payload, time.time()))

    def _admit(self, site: str) -> bool:
        """Whether messages of `site` are taken: a name of the list, or (no list) one already
        known or a new one while fewer than max_sites are."""
        with self._lock:
            if site in self._sites:
                return True
            ok = (
                site in self.allowed_sites
                if self.allowed_sites
                else len(self._sites) < self.max_sites
            )
            ok = ok and 0 < len(site) <= 200 and site.isprintable()
            if ok:
                self._sites.add(site)
                return True
            self.counts["refused_sites"] += 1
            if len(self._refused) < 10:
                self._refused.append(site)
        why = (
            "not in [control_room] sites"
            if self.allowed_sites
            else f"already {self.max_sites} sites ([control_room] max_sites)"
        )
        self._warn("site", f"control room: a message of site {site[:80]!r} refused: {why}")
        return False

    def _room_incident(self, site: str, kind: str, detail: str, priority: int = 2) -> None:
        """A control-room incident of `kind` about `site` (one while active), cleared once no
        such thing came for QUIET_S."""
        self._bad_at[(site, kind)] = time.monotonic()
        try:
            if (
                self.store.raise_room_incident(site, kind, priority, detail[:500], time.time())
                is not None
            ):
                self.counts["room_incidents"] += 1
        except StoreError as e:
            self.counts["store_errors"] += 1
            logger.error("control room: %s", e)

    def _clear_quiet(self) -> None:
        now = time.monotonic()
        for (site, kind), at in list(self._bad_at.items()):
            if now - at > QUIET_S:
                try:
                    self.store.clear_room_incidents(site, kind, time.time())
                except StoreError as e:
                    self.counts["store_errors"] += 1
                    logger.error("control room: %s", e)
                    continue
                del self._bad_at[(site, kind)]

    def _note_refused(self) -> None:
        with self._lock:
            names, self._refused = self._refused, []
        if names:
            shown = ", ".join(repr(n[:40]) for n in names)
            why = (
                "not in [control_room] sites"
                if self.allowed_sites
                else f"beyond [control_room] max_sites = {self.max_sites}"
            )
            self._room_incident(
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
                    self.marks, self.imarks = self.store.marks(), self.store.incident_marks()
                except StoreError as e:
                    logger.error("control room: %s", e)

    def _step(self) -> None:
        with self._lock:
            batch = list(self._queue)
            self._queue.clear()
        per_site: dict[str, list[dict]] = {}
        changes: dict[str, list[dict]] = {}
        self._note_refused()
        self._clear_quiet()
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
                self._done(site, payload)
                continue
            incidents = what == INCIDENTS
            if what != EVENTS and not incidents:
                continue
            outbox += 1
            msg = _numbered(payload, "seq" if incidents else "id")
            if (
                msg is None
                or msg.get("site", site) != site
                or (incidents and not _incident_change(msg))
            ):
                self.counts["malformed"] += 1
                continue
            self._accept(site, incidents, msg, per_site, changes)
        if self._held:  # a worker's share: what came before them may be in the store now
            self._release_held(per_site, changes)
        now = time.time()
        batch_sites = set(per_site) | set(changes)
        if batch_sites:
            try:  # one transaction for the whole batch
                new, written = self.store.put_batch(
                    {s: (v, self.marks[s]) for s, v in per_site.items()},
                    {s: (v, self.imarks[s]) for s, v in changes.items()},
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
                self._confirm(site)
        if not outbox:
            self._progress = time.monotonic()  # nothing waited to be stored
        self._flush_summaries()
        self._send_commands()
        self._leave_unwatched()
        self._prune()
        self._rate.append((now, self.counts["messages"]))
        for site, seen in list(self._seen.items()):
            if now - seen > self.offline_after_s and self._available.get(site) != "offline":
                self._available[site] = "offline"
                logger.warning("control room: site %s silent for %.0f s: offline", site, now - seen)
                self._set_state(site, "offline")

    def _accept(
        self,
        site: str,
        incidents: bool,
        msg: dict,
        per_site: dict,
        changes: dict,
        held_since: float | None = None,
    ) -> None:
        """An outbox message to store when nothing is missing before it; else a gap (one
        worker: a replay asked) or, sharing the sites with other workers, held a moment (the
        one before it may be another worker's, stored by it meanwhile)."""
        marks = self.imarks if incidents else self.marks
        mark = marks.get(site, 0)
        number = msg["seq" if incidents else "id"]
        if number <= mark:  # stored already (and perhaps pruned since): a resend
            self.counts["duplicates"] += 1
            return
        if self._too_far(site, incidents, number, mark):
            return
        if msg["prev"] > mark:
            now = time.monotonic()
            since = now if held_since is None else held_since
            if self.shared and now - since < HOLD_S:
                held = self._held.setdefault((site, incidents), {})
                if len(held) < MAX_HELD:
                    held[msg["prev"]] = (msg, since)
                    return
                self.counts["dropped"] += 1  # not confirmed: its site sends it again
            self.counts["gaps"] += 1
            self._ask_replay(site, mark, incidents=incidents)
            return
        (changes if incidents else per_site).setdefault(site, []).append(msg)
        marks[site] = number

    def _too_far(self, site: str, incidents: bool, number: int, mark: int) -> bool:
        """Whether `number` is further beyond what the site announced (or, before its first
        heartbeat, beyond the mark) than `ids_ahead`: then it is not taken (counted; an
        incident when the site had announced less; a heartbeat announcing it asks for it)."""
        announced = (self._announced_i if incidents else self._announced).get(site)
        if number - max(mark, announced or 0) <= self.ids_ahead:
            return False
        self.counts["ahead"] += 1
        if announced is None:  # its first heartbeat will say (and a replay bring it)
            return True
        key = (site, incidents)
        if number > self._ahead.get(key, 0):
            self._ahead[key] = number
        what = "incident change" if incidents else "event"
        self._warn(
            "ahead",
            f"control room: site {site}'s {what} {number} refused: more than "
            f"{self.ids_ahead} beyond the last it announced ({announced})",
        )
        self._room_incident(
            site,
            "site_ids_ahead",
            f"an {what} numbered {number} refused: the site announced {announced} as its last",
        )
        return True

    def _release_held(self, per_site: dict, changes: dict) -> None:
        """The held messages again, in order, after the marks are read from the shared
        store (what the other workers stored); any held past HOLD_S is a gap."""
        try:
            stored = (self.store.marks(), self.store.incident_marks())
        except StoreError:
            stored = ({}, {})
        for marks, theirs in ((self.marks, stored[0]), (self.imarks, stored[1])):
            for site, m in theirs.items():
                if m > marks.get(site, 0):
                    marks[site] = m
        held, self._held = self._held, {}
        for (site, incidents), items in held.items():
            for _, (msg, since) in sorted(items.items()):
                self._accept(site, incidents, msg, per_site, changes, held_since=since)

    def _put_each(self, per_site: dict, changes: dict, now: float) -> set[str]:
        """Each site's batch in its own transaction; the sites stored."""
        done = set()
        for site in set(per_site) | set(changes):
            try:
                if site in per_site:
                    events = per_site[site]
                    new = self.store.put_events(site, events, self.marks[site], now)
                    self.counts["stored"] += new
                    self.counts["duplicates"] += len(events) - new
                if site in changes:
                    self.counts["incident_changes"] += self.store.put_incidents(
                        site, changes[site], self.imarks[site], now
                    )
            except StoreError as e:  # not confirmed: the site sends them again
                self.counts["store_errors"] += 1
                self.marks, self.imarks = self.store.marks(), self.store.incident_marks()
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

    def _confirm(self, site: str) -> None:
        """The site's marks of both streams on its `log/confirmed` (retained: one message)."""
        body = confirmed_body(self.marks.get(site, 0), self.imarks.get(site, 0))
        self.client.publish(site_topic(self.prefix, site, CONFIRMED), body, qos=1, retain=True)

    def _beat(self, site: str, payload: bytes, at: float) -> None:
        """A site's heartbeat: its log's last id beyond the mark (the last events were lost
        and nothing later shows it) asks for a replay; its clock's offset is kept."""
        try:
            beat = json.loads(payload)
            last, sent = beat["last_id"], float(beat["time"])
            if (
                isinstance(last, bool)
                or not isinstance(last, int)
                or not 0 <= last <= _MAX_ID
                or not math.isfinite(sent)
            ):
                raise ValueError("out of range")
        except (ValueError, TypeError, KeyError, UnicodeDecodeError, OverflowError, RecursionError):
            self.counts["malformed"] += 1
            return
        self.clock_offsets[site] = offset = round(sent - at, 3)
        if abs(offset) > CLOCK_WARN_S and site not in self._clock_warned:
            self._clock_warned.add(site)
            logger.warning(
                "control room: site %s's clock is %+.1f s from this machine's", site, offset
            )
        self._clock(site, offset)
        summary = _summary(beat)
        if summary:
            summary["clock_offset_s"] = round(offset, 1)  # in the store: every worker's
        if summary and self._summaries.get(site) != summary:
            self._summaries[site] = summary
            self._summaries_dirty.add(site)
        if self._available.get(site) != "offline":
            self._set_state(site, "live")
        # what the previous heartbeat announced is still not stored (not merely on its way)
        mark = self.marks.get(site, 0)
        if mark < self._announced.get(site, 0):
            self.counts["behind"] += 1
            self._ask_replay(site, mark)
        self._announced[site] = last
        seq = beat.get("last_incident_seq")
        if isinstance(seq, int) and not isinstance(seq, bool) and 0 <= seq <= _MAX_ID:
            imark = self.imarks.get(site, 0)
            if imark < self._announced_i.get(site, 0):
                self.counts["behind"] += 1
                self._ask_replay(site, imark, incidents=True)
            self._announced_i[site] = seq
        for incidents, now_last in ((False, last), (True, self._announced_i.get(site, 0))):
            held = self._ahead.get((site, incidents))
            if held is not None and now_last >= held:  # it was real: the replay brings it
                del self._ahead[(site, incidents)]
                marks = self.imarks if incidents else self.marks
                self._ask_replay(site, marks.get(site, 0), incidents=incidents)

    def _clock(self, site: str, offset: float) -> None:
        """A control-room incident while the site's clock is off by more than the bound."""
        now = time.time()
        try:
            if abs(offset) > self.clock_tolerance_s and site not in self._clock_off:
                self._clock_off.add(site)
                if (
                    self.store.raise_room_incident(
                        site,
                        "site_clock",
                        3,
                        f"the site's clock is {offset:+.1f} s from the control room's",
                        now,
                    )
                    is not None
                ):
                    self.counts["room_incidents"] += 1
            elif abs(offset) <= self.clock_tolerance_s and site in self._clock_off:
                self._clock_off.discard(site)
                self.store.clear_room_incidents(site, "site_clock", now)
        except StoreError as e:
            self.counts["store_errors"] += 1
            logger.error("control room: %s", e)

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

    # --- a site's page: its plan and its people while looked at --------------------------

    def _latest(self, site: str, what: str, payload: bytes) -> None:
        if len(payload) > MAX_PLAN_BYTES:
            return
        try:
            doc = json.loads(payload) if payload else None
        except (ValueError, UnicodeDecodeError, RecursionError):
            doc = None
        if doc is not None and (not isinstance(doc, dict) or not _sane(doc, -MAX_DEPTH)):
            doc = None  # a plan nests deeper than an event: zones, cameras, points
        with self._lock:
            if what == PLAN:
                if doc is None:
                    self._plans.pop(site, None)
                elif len(self._plans) < MAX_SITES or site in self._plans:
                    self._plans[site] = doc
            elif site in self._watched and doc is not None:
                self._people[site] = (time.time(), doc)

    def known_sites(self) -> set[str]:
        """The sites with a plan (any thread; the store holds every site heard of)."""
        with self._lock:
            return set(self._plans)

    def watch(self, site: str) -> dict:
        """The site's plan and people now; following its people topic from now on, until
        nobody asked for WATCH_S."""
        with self._lock:
            new = site not in self._watched
            self._watched[site] = time.monotonic()
            plan = self._plans.get(site)
            seen = self._people.get(site)
        if new:
            self.client.subscribe(site_topic(self.prefix, site, PEOPLE), 0)
        people = None
        if seen is not None:
            people = {**seen[1], "received_at": round(seen[0], 3)}
        return {"plan": plan, "people": people, "console_url": (plan or {}).get("console_url")}

    def _leave_unwatched(self) -> None:
        now = time.monotonic()
        with self._lock:
            gone = [s for s, t in self._watched.items() if now - t > WATCH_S]
            for s in gone:
                del self._watched[s]
                self._people.pop(s, None)
        for s in gone:
            self.client.unsubscribe(site_topic(self.prefix, s, PEOPLE))

    # --- acknowledgements asked of sites -------------------------------------------------

    def ask_ack(self, site: str, incident: int, by: str) -> int:
        """Ask `site` to acknowledge its `incident` as `by` (any thread); the command's id.
        StoreError when it cannot be stored."""
        command = self.store.add_command(site, incident, by, time.time())
        with self._lock:
            self._commands[command] = [site, incident, by, 0.0]
        return command

    def _send_commands(self) -> None:
        now = time.monotonic()
        if self.shared and now - self._pending_checked > self.command_resend_s:
            self._pending_checked = now  # answered through another worker: not sent again
            try:
                open_ = {c for c, *_ in self.store.pending_commands()}
            except StoreError:
                open_ = None
            if open_ is not None:
                with self._lock:
                    for c in [c for c in self._commands if c not in open_]:
                        del self._commands[c]
        with self._lock:
            due = [(c, v) for c, v in self._commands.items() if now - v[3] >= self.command_resend_s]
            for _, v in due:
                v[3] = now
        for command, (site, incident, by, _) in due:
            body = ack_body(command, incident, by, self.name)
            self.client.publish(site_topic(self.prefix, site, COMMAND_ACK), body, qos=1)
            self.counts["commands_sent"] += 1

    def _done(self, site: str, payload: bytes) -> None:
        try:
            done = json.loads(payload)
            command, result = int(done["command"]), str(done["result"])[:32]
        except (ValueError, TypeError, KeyError, UnicodeDecodeError):
            self.counts["malformed"] += 1
            return
        with self._lock:
            mine = self._commands.get(command)
            if mine is not None and mine[0] != site:  # not this site's command: kept
                return
            self._commands.pop(command, None)
        if mine is None:
            if self.shared:  # another worker's: answered in the shared store
                try:
                    self.store.finish_command(command, result, time.time(), site=site)
                except StoreError as e:
                    self.counts["store_errors"] += 1
                    logger.error("control room: %s", e)
            return
        try:
            self.store.finish_command(command, result, time.time())
        except StoreError as e:
            self.counts["store_errors"] += 1
            logger.error("control room: %s", e)
        self.counts["commands_done"] += 1
        if result != "acknowledged":
            logger.info(
                "control room: site %s answered the acknowledgement of incident %s: %s",
                site,
                mine[1],
                result,
            )

    def _set_state(self, site: str, state: str) -> None:
        """The site's state in the store, written only when it changes; offline raises a
        control-room incident, live clears it."""
        if self._state.get(site) == state:
            return
        now = time.time()
        try:
            self.store.set_site(site, state=state, last_seen=now)
            if state == "offline":
                if (
                    self.store.raise_room_incident(
                        site, "site_offline", 2, "the site is offline", now
                    )
                    is not None
                ):
                    self.counts["room_incidents"] += 1
            else:
                self.store.clear_room_incidents(site, "site_offline", now)
        except StoreError as e:
            self.counts["store_errors"] += 1
            logger.error("control room: %s", e)
            return
        self._state[site] = state

    def _ask_replay(self, site: str, mark: int, incidents: bool = False) -> None:
        now = time.monotonic()
        key = (site, incidents)
        if now - self._asked.get(key, -1e9) < self.replay_every_s:
            return
        self._asked[key] = now
        self.counts["replays"] += 1
        self.client.publish(
            site_topic(self.prefix, site, REPLAY), replay_body(mark, incidents), qos=1
        )

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

    def figures(self) -> dict:
        with self._lock:
            queued = len(self._queue)
        f = dict(self.counts, queued=queued, connected=self.connected, subscribed=self.subscribed)
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


def _numbered(payload: bytes, key: str) -> dict | None:
    """An outbox message with an int `key` and prev, every number in it within what a store
    holds (integers of 64 bits, finite floats), nested at most MAX_DEPTH deep; or None."""
    try:
        e = json.loads(payload)
    except (ValueError, UnicodeDecodeError, RecursionError):
        return None
    if not isinstance(e, dict) or not _sane(e):
        return None
    for k in (key, "prev"):
        v = e.get(k)
        if isinstance(v, bool) or not isinstance(v, int) or not 0 <= v <= _MAX_ID:
            return None
    p = e.get("priority")
    if p is not None and (isinstance(p, bool) or p not in (1, 2, 3, 4)):
        return None
    return e


def _sane(value: Any, depth: int = 0) -> bool:
    """Whether every number in `value` fits a store (int64, finite), every string and key is
    at most MAX_TEXT characters, every object and list at most MAX_ITEMS long, and it nests
    at most MAX_DEPTH deep."""
    if depth > MAX_DEPTH:
        return False
    if isinstance(value, bool) or value is None:
        return True
    if isinstance(value, str):
        return len(value) <= MAX_TEXT
    if isinstance(value, int):
        return -(2**63) <= value <= _MAX_ID
    if isinstance(value, float):
        return math.isfinite(value)
    if isinstance(value, dict):
        return len(value) <= MAX_ITEMS and all(
            len(k) <= MAX_TEXT and _sane(v, depth + 1) for k, v in value.items()
        )
    if isinstance(value, list):
        return len(value) <= MAX_ITEMS and all(_sane(v, depth + 1) for v in value)
    return False


def _summary(beat: dict) -> dict:
    """A heartbeat's summary of its site, each field checked: a short status, counts in
    range; anything else left out."""
    out: dict[str, Any] = {}
    status = beat.get("status")
    if isinstance(status, str) and 0 < len(status) <= MAX_STATUS and status.isprintable():
        out["status"] = status
    for k in SUMMARY_COUNTS:
        v = beat.get(k)
        if isinstance(v, int) and not isinstance(v, bool) and 0 <= v <= MAX_COUNT:
            out[k] = v
    return out


def _incident_change(msg: dict) -> bool:
    rec = msg.get("incident")
    if not isinstance(rec, dict):
        return False
    i = rec.get("id")
    return isinstance(i, int) and not isinstance(i, bool) and 0 <= i <= _MAX_ID
