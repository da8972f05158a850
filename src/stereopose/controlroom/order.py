"""The outbox protocol's receiving end (docs/mqtt.md#the-event-log-outbox), per site and
stream (events, incident changes): the mark (the last number stored), what each heartbeat
announced, and what is taken. A message whose `prev` is at most the mark is taken and raises
the mark; one beyond it is a gap (a replay after the mark asked for, at most once per
`replay_every_s`) or, with several workers sharing the sites, held HOLD_S for the one before
it; a number more than `ids_ahead` beyond what the site announced is refused (a broken site
would blind itself: every later real event would look like a resend)."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import TYPE_CHECKING

from stereopose.controlroom.room import RoomIncidents
from stereopose.controlroom.store import ControlStore, StoreError
from stereopose.site.wire import CONFIRMED, REPLAY, confirmed_body, replay_body, site_topic

if TYPE_CHECKING:
    import paho.mqtt.client as paho

HOLD_S = 3.0  # a worker holds a message this long for the one before it (another worker's)
MAX_HELD = 10_000  # messages held per site and stream at most

Batch = dict[str, list[dict]]  # site -> the messages taken, in order


class Order:
    """The ingest thread's marks and ordering. room: the control room's incidents, with the
    store and the ingest's figures (duplicates, gaps, dropped, replays, ahead, behind) it
    shares; warn(kind, text): the ingest's rate-limited log."""

    def __init__(
        self,
        client: paho.Client,
        prefix: str,
        room: RoomIncidents,
        warn: Callable[[str, str], None],
        *,
        shared: bool = False,
        ids_ahead: int = 100_000,
        replay_every_s: float = 2.0,
    ) -> None:
        store: ControlStore = room.store
        self.store, self.client, self.prefix = store, client, prefix
        self.counts, self.room, self.warn = room.counts, room, warn
        self.shared, self.ids_ahead = shared, int(ids_ahead)
        self.replay_every_s = float(replay_every_s)
        self.marks = store.marks()
        self.imarks = store.incident_marks()
        self.announced: dict[str, int] = {}  # site -> the last id its last heartbeat gave
        self.announced_i: dict[str, int] = {}  # ... and the last incident change's seq
        self._ahead: dict[tuple[str, bool], int] = {}  # the highest number refused as ahead
        # (site, incidents?) -> prev -> (message, held since): a worker's out-of-order share
        self._held: dict[tuple[str, bool], dict[int, tuple[dict, float]]] = {}
        self._asked: dict[tuple[str, bool], float] = {}  # (site, incidents) -> last replay

    def reload(self) -> None:
        """The marks back to what the store committed (a batch that failed confirms nothing,
        and its sites send again what it held). StoreError when the store cannot say."""
        self.marks, self.imarks = self.store.marks(), self.store.incident_marks()

    def accept(
        self,
        site: str,
        incidents: bool,
        msg: dict,
        per_site: Batch,
        changes: Batch,
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
            self.ask_replay(site, mark, incidents=incidents)
            return
        (changes if incidents else per_site).setdefault(site, []).append(msg)
        marks[site] = number

    def _too_far(self, site: str, incidents: bool, number: int, mark: int) -> bool:
        """Whether `number` is further beyond what the site announced (or, before its first
        heartbeat, beyond the mark) than `ids_ahead`: then it is not taken (counted; an
        incident when the site had announced less; a heartbeat announcing it asks for it)."""
        announced = (self.announced_i if incidents else self.announced).get(site)
        if number - max(mark, announced or 0) <= self.ids_ahead:
            return False
        self.counts["ahead"] += 1
        if announced is None:  # its first heartbeat will say (and a replay bring it)
            return True
        key = (site, incidents)
        if number > self._ahead.get(key, 0):
            self._ahead[key] = number
        what = "incident change" if incidents else "event"
        self.warn(
            "ahead",
            f"control room: site {site}'s {what} {number} refused: more than "
            f"{self.ids_ahead} beyond the last it announced ({announced})",
        )
        self.room.bad(
            site,
            "site_ids_ahead",
            f"an {what} numbered {number} refused: the site announced {announced} as its last",
        )
        return True

    def release_held(self, per_site: Batch, changes: Batch) -> None:
        """The held messages again, in order, after the marks are read from the shared
        store (what the other workers stored); any held past HOLD_S is a gap."""
        if not self._held:
            return
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
                self.accept(site, incidents, msg, per_site, changes, held_since=since)

    def announce(self, site: str, last: int, seq: int | None) -> None:
        """A heartbeat's last event id and incident seq: what the previous heartbeat
        announced and is still not stored (not merely on its way) is asked for again, and a
        number refused as ahead that the site now announces is asked for too."""
        mark = self.marks.get(site, 0)
        if mark < self.announced.get(site, 0):
            self.counts["behind"] += 1
            self.ask_replay(site, mark)
        self.announced[site] = last
        if seq is not None:
            imark = self.imarks.get(site, 0)
            if imark < self.announced_i.get(site, 0):
                self.counts["behind"] += 1
                self.ask_replay(site, imark, incidents=True)
            self.announced_i[site] = seq
        for incidents, now_last in ((False, last), (True, self.announced_i.get(site, 0))):
            held = self._ahead.get((site, incidents))
            if held is not None and now_last >= held:  # it was real: the replay brings it
                del self._ahead[(site, incidents)]
                marks = self.imarks if incidents else self.marks
                self.ask_replay(site, marks.get(site, 0), incidents=incidents)

    def ask_replay(self, site: str, mark: int, incidents: bool = False) -> None:
        now = time.monotonic()
        key = (site, incidents)
        if now - self._asked.get(key, -1e9) < self.replay_every_s:
            return
        self._asked[key] = now
        self.counts["replays"] += 1
        self.client.publish(
            site_topic(self.prefix, site, REPLAY), replay_body(mark, incidents), qos=1
        )

    def confirm(self, site: str) -> None:
        """The site's marks of both streams on its `log/confirmed` (retained: one message)."""
        body = confirmed_body(self.marks.get(site, 0), self.imarks.get(site, 0))
        self.client.publish(site_topic(self.prefix, site, CONFIRMED), body, qos=1, retain=True)
