"""A site's page in the control room: its retained plan (zones, cameras, console_url), and
its people followed while the page is looked at (subscribed on demand, left WATCH_S after the
page last asked)."""

from __future__ import annotations

import json
import threading
import time
from typing import TYPE_CHECKING

from stereopose.controlroom.checks import MAX_DEPTH, sane
from stereopose.site.wire import PEOPLE, PLAN, site_topic

if TYPE_CHECKING:
    import paho.mqtt.client as paho

WATCH_S = 15.0  # a site's people are followed this long after its page last looked
MAX_PLAN_BYTES = 1 << 20  # a plan or people message larger than this is ignored
MAX_SITES = 100_000  # plans kept at most


class SitePages:
    """The plans and watched people of every site (any thread). client: the ingest's paho
    client (subscribes and unsubscribes the people topics); prefix: the topics' prefix."""

    def __init__(self, client: paho.Client, prefix: str) -> None:
        self.client, self.prefix = client, prefix
        self._lock = threading.Lock()
        self._plans: dict[str, dict] = {}  # site -> its retained plan
        self._people: dict[str, tuple[float, dict]] = {}  # watched site -> (when, latest)
        self._watched: dict[str, float] = {}  # site -> when its page last looked (monotonic)

    def latest(self, site: str, what: str, payload: bytes) -> None:
        """A plan or people message: the latest kept (one a site), a bad one dropped."""
        if len(payload) > MAX_PLAN_BYTES:
            return
        try:
            doc = json.loads(payload) if payload else None
        except (ValueError, UnicodeDecodeError, RecursionError):
            doc = None
        if doc is not None and (not isinstance(doc, dict) or not sane(doc, -MAX_DEPTH)):
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
        """The sites with a plan."""
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

    def follow_again(self, client: paho.Client) -> None:
        """A new connection: the pages being looked at follow their people again."""
        with self._lock:
            watched = list(self._watched)
        for site in watched:
            client.subscribe(site_topic(self.prefix, site, PEOPLE), 0)

    def leave_unwatched(self) -> None:
        now = time.monotonic()
        with self._lock:
            gone = [s for s, t in self._watched.items() if now - t > WATCH_S]
            for s in gone:
                del self._watched[s]
                self._people.pop(s, None)
        for s in gone:
            self.client.unsubscribe(site_topic(self.prefix, s, PEOPLE))
