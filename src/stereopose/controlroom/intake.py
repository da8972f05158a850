"""What paho's thread does with a site's message before the ingest's thread sees it: the
topic's byte bound, the site's name admitted (an enrolled site's, controlroom.enrolment, or
one of `[control_room] sites`: no other name takes a place), a plan or people message kept at
once (one a site), and anything else appended to a bounded queue (at the bound dropped and
counted: its site sends it again, since it is not confirmed). Every refusal is counted and
logged at most once a minute a kind."""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Iterable

from stereopose.controlroom.site_pages import MAX_PLAN_BYTES, SitePages
from stereopose.site.wire import (
    AVAILABLE,
    COMMAND_DONE,
    EVENTS,
    HEARTBEAT,
    INCIDENTS,
    PEOPLE,
    PLAN,
    split_topic,
)

logger = logging.getLogger(__name__)

QUEUE = 100_000  # messages waiting for the ingest's thread at most
WARN_EVERY_S = 60.0  # a kind of bad message logged at most this often
# bytes of a message on these topics at most (the outbox's and heartbeat's come from settings)
SMALL_TOPICS = {AVAILABLE: 64, COMMAND_DONE: 1024}
NOT_ENROLLED = "not enrolled (stereopose control-room sites add NAME)"


class Intake:
    """The bounded intake (paho's thread puts, the ingest's thread takes). counts: the
    ingest's figures (oversize, refused_sites, dropped, malformed); enrolled: the sites
    enrolled now (`enrol` gives them again when they change); sites: `[control_room] sites`,
    taken as well."""

    def __init__(
        self,
        prefix: str,
        pages: SitePages,
        counts: dict[str, int],
        enrolled: Iterable[str],
        *,
        sites: tuple[str, ...] | list[str] = (),
        max_event_bytes: int = 65_536,
        max_heartbeat_bytes: int = 8192,
        queue_size: int = QUEUE,
    ) -> None:
        self.prefix, self.pages, self.counts = prefix, pages, counts
        self.listed = frozenset(sites)
        self.queue_size = int(queue_size)
        self.max_bytes = {
            **SMALL_TOPICS,
            EVENTS: int(max_event_bytes),
            INCIDENTS: int(max_event_bytes),
            HEARTBEAT: int(max_heartbeat_bytes),
            PLAN: MAX_PLAN_BYTES,
            PEOPLE: MAX_PLAN_BYTES,
        }
        self._sites = self.listed | frozenset(enrolled)  # the names admitted
        self._refused: list[str] = []  # site names refused since the ingest last looked
        self._queue: deque[tuple[str, str, bytes, float]] = deque()
        self._lock = threading.Lock()
        self._warned_at: dict[str, float] = {}  # kind of bad message -> when last logged

    def put(self, topic: str, payload: bytes) -> None:
        """A message from the broker: refused (counted), kept, or queued."""
        parts = split_topic(self.prefix, topic)
        if parts is None:
            return
        site, what = parts
        limit = self.max_bytes.get(what)
        if limit is None:  # not a topic of the protocol (nor an answer to one)
            return
        if len(payload) > limit:
            self.count("oversize")
            self.warn(
                "oversize",
                f"control room: a {len(payload)}-byte message on "
                f"{str(topic)[:200]!r} refused (at most {limit})",
            )
            return
        if not self._admit(site):
            return
        if what in (PLAN, PEOPLE):  # the latest only, kept at once (bounded: one a site)
            self.pages.latest(site, what, payload)
            return
        with self._lock:
            if len(self._queue) >= self.queue_size:
                self.counts["dropped"] += 1  # not confirmed: its site sends it again
                return
            self._queue.append((site, what, payload, time.time()))

    def take(self) -> list[tuple[str, str, bytes, float]]:
        """Every (site, topic's last part, payload, when it came) queued, in arrival order."""
        with self._lock:
            batch = list(self._queue)
            self._queue.clear()
        return batch

    def queued(self) -> int:
        with self._lock:
            return len(self._queue)

    def count(self, what: str) -> None:
        with self._lock:
            self.counts[what] += 1

    def enrol(self, enrolled: Iterable[str]) -> None:
        """The sites enrolled now (added and removed ones take effect with the next message)."""
        admitted = self.listed | frozenset(enrolled)
        with self._lock:
            self._sites = admitted

    def admitted(self) -> frozenset[str]:
        with self._lock:
            return self._sites

    def refused(self) -> tuple[list[str], str]:
        """The site names refused since last asked (ten at most) and why."""
        with self._lock:
            names, self._refused = self._refused, []
        return names, NOT_ENROLLED

    def warn(self, kind: str, text: str) -> None:
        """Log `text` unless a message of this kind was logged within the last minute."""
        now = time.monotonic()
        if now - self._warned_at.get(kind, -WARN_EVERY_S) >= WARN_EVERY_S:
            self._warned_at[kind] = now
            logger.warning("%s", text)

    def _admit(self, site: str) -> bool:
        """Whether messages of `site` are taken: an enrolled or listed name only."""
        with self._lock:
            if site in self._sites:
                return True
            self.counts["refused_sites"] += 1
            if len(self._refused) < 10:
                self._refused.append(site)
        self.warn("site", f"control room: a message of site {site[:80]!r} refused: {NOT_ENROLLED}")
        return False
