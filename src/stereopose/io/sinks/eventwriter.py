"""The event log's writer: events (and the incident records of their step) in an SQLite
database, the log every reader of the site's history uses (docs/formats.md)."""

from __future__ import annotations

import json
import logging
import sqlite3
import time
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from stereopose.alarms import Change, IncidentRecord
from stereopose.errors import OutputError
from stereopose.io.records import event_record, event_row
from stereopose.io.sinks.base import FrameResult
from stereopose.io.sinks.eventdb import (
    connect_writer,
    create_schema,
    raise_marks,
    take,
)
from stereopose.io.sinks.events import COLUMNS, _EventSink
from stereopose.io.sinks.incidents import upsert_incidents
from stereopose.io.sinks.spill import Spill, store_spill
from stereopose.io.writing import make_folder
from stereopose.secrets import redact_all
from stereopose.types import Event

__all__ = ["SqliteSink", "mask_sources"]

logger = logging.getLogger(__name__)


def mask_sources(db: sqlite3.Connection) -> int:
    """Every run's `source` without a URL's password (logs of earlier versions stored camera
    URLs as written); the old text overwritten in the file (secure_delete), not left in freed
    pages. Returns the rows changed."""
    rows = db.execute("SELECT id, source FROM runs WHERE source LIKE '%://%@%'").fetchall()
    changed = [(redact_all(src), rid) for rid, src in rows if redact_all(src) != src]
    if changed:
        db.execute("PRAGMA secure_delete = ON")
        with db:
            db.executemany("UPDATE runs SET source = ? WHERE id = ?", changed)
        db.execute("PRAGMA wal_checkpoint(TRUNCATE)")
        logger.warning(
            "%d run(s) of the event log named a camera URL with its password: masked", len(changed)
        )
    return len(changed)


@dataclass(frozen=True)
class LockWaits:
    """How the event log's writer waits on the file's lock: a write waits busy_s, then is
    kept (at most buffer_size events) and tried again every retry_s; opening waits
    open_timeout_s; closing writes what is kept for up to close_timeout_s."""

    busy_s: float = 0.05
    retry_s: float = 0.2
    buffer_size: int = 100_000
    open_timeout_s: float = 5.0
    close_timeout_s: float = 10.0


class SqliteSink(_EventSink):
    """Events in an SQLite database (WAL), one transaction per write with events.

    The frame loop is never held up by another process's write lock: a write waits busy_s at
    most; if the log is still locked (or fails otherwise), the events are kept in memory, in
    order (at most buffer_size: more are dropped and counted), and stored with the next
    frame's, tried again after retry_s, doubling to 2 s. Readers never block it (WAL). Events
    that wait are also appended to `<name>.pending.jsonl` (io.sinks.spill) until they are
    stored: a run killed meanwhile leaves them there, and the next start reads them (the
    zones they leave open are closed) and stores them in the log. `close` keeps trying for
    close_timeout_s; what is still not stored then is appended to `<name>.unstored.jsonl`
    beside the database (the events contract) and `incomplete` says so (the next start
    stores them in the log too, from the pending file).

    Person ids: with first_id, the sink records the ids its run gives in `id_reservations`,
    id_block at a time, extended when a frame's highest id comes within half a block of its
    end (a record beside the frames; a log read by an earlier version still sees them). What
    keeps ids from being given twice is site.person_ids: serve's tracker takes each id from
    a block reserved on the log's `persons` mark before the id is given, so no frame (nor
    segment, MQTT message) can hold an id a restart would give again. A clean close records
    the run's end time. wall_start: the Unix time of t = 0, recorded in
    the run's row (an event's wall time is wall_start + t).
    """

    def __init__(
        self,
        path: str | Path,
        site: str | None = None,
        source: str | None = None,
        *,
        waits: LockWaits = LockWaits(),
        first_id: int | None = None,
        id_block: int = 1000,
        wall_start: float | None = None,
    ) -> None:
        self.path = Path(path)
        if id_block < 2:
            raise ValueError(f"id_block must be at least 2, got {id_block}")
        self.id_block = id_block
        self.reserved: int | None = None  # ids below it are reserved (committed); None: off
        self._want: int | None = None  # a reservation not committed yet
        self.busy_s, self.retry_s, self.buffer_size = waits.busy_s, waits.retry_s, waits.buffer_size
        self.close_timeout_s = waits.close_timeout_s
        try:
            make_folder(self.path.parent)
        except OSError as e:
            raise OutputError(
                f"{self.path}: cannot write the event database: {e.strerror}"
            ) from None
        try:
            self.db = connect_writer(self.path, waits.open_timeout_s, create=True)
            create_schema(self.db)
            raise_marks(self.db)  # an earlier version's log: its marks start above its ids
            self.spill = Spill(self.path)
            self._old_spill = not self._store_spill()
            mask_sources(self.db)  # a log an earlier version wrote: no camera's password
            cur = self.db.execute(
                "INSERT INTO runs(started, site, source, wall_start) VALUES (?, ?, ?, ?)",
                (time.time(), site, None if source is None else redact_all(source), wall_start),
            )
            assert cur.lastrowid is not None  # an INSERT's row
            self.run = int(cur.lastrowid)
            if first_id is not None:
                # the first block, committed before the tracker gives an id
                self.db.execute(
                    "INSERT INTO id_reservations(run, upto) VALUES (?, ?)",
                    (self.run, first_id + id_block),
                )
                self.reserved = first_id + id_block
            self._busy(waits.busy_s)
        except sqlite3.DatabaseError as e:
            raise OutputError(f"{self.path}: cannot open the event database: {e}") from None
        self.committed = self.dropped = 0
        self.pending: deque[Event] = deque()
        # incidents changed since the last store: id -> (record, wall_start of its times),
        # stored with the next events (one per incident: bounded by the book)
        self.incidents: dict[int, tuple[IncidentRecord, float | None]] = {}
        self._incidents_spilled: dict[int, tuple] = {}  # of those, the ones in the spill file
        self.wall_start = wall_start
        self._spilled = 0  # the first pending events, kept in the spill file too
        self.incomplete: str | None = None
        self.kept_in: Path | None = None  # where close put the events it could not store
        self._next_try = 0.0
        self._delay = waits.retry_s
        self._error: str | None = None  # why the last store failed; None: it did not

    def _store_spill(self) -> bool:
        """The events an earlier run left waiting beside the log, stored; whether that is done
        (if not, tried again before the next store; the file is kept until it is)."""
        try:
            store_spill(self.db, self.path)
        except sqlite3.Error as e:
            logger.warning(
                "%s: cannot store the events an earlier run left waiting now: %s", self.path, e
            )
            return False
        return True

    def put_incidents(self, records: Sequence[IncidentRecord]) -> None:
        """Incident records (alarms.IncidentRecord) to store with the next events; a later
        record of an incident replaces an earlier one not stored yet."""
        for rec in records:
            self.incidents[int(rec.id)] = (rec, self.wall_start)

    def _busy(self, seconds: float) -> None:
        self.db.execute(f"PRAGMA busy_timeout = {max(0, int(1000 * seconds))}")

    def write(self, frame: FrameResult) -> None:
        if self.reserved is not None:
            self._reserve(frame.people3d.ids, self.reserved)
        self.write_events(frame.events)

    def _reserve(self, ids: np.ndarray, reserved: int) -> None:
        """Asks for more ids when `ids` come within half a block of the reservation's end
        (`reserved`; the next store commits it, with the frame's events or on its own)."""
        if len(ids) and int(ids.max()) >= reserved - self.id_block // 2:
            self._want = max(self._want or 0, int(ids.max()) + self.id_block)

    def write_events(self, events: Sequence[Event]) -> None:
        if events:
            room = self.buffer_size - len(self.pending)
            if len(events) > room:
                self.dropped += len(events) - max(room, 0)
                logger.error(
                    "%s: %d event(s) waiting to be stored; %d dropped (%d so far)",
                    self.path,
                    len(self.pending),
                    len(events) - max(room, 0),
                    self.dropped,
                )
                events = events[: max(room, 0)]
            self.pending.extend(events)
        if (self.pending or self._want is not None or self.incidents) and (
            time.monotonic() >= self._next_try
        ):
            self._store()
        self._keep_waiting()

    def _keep_waiting(self) -> None:
        """The events and incident records still waiting, kept on disk too (the other sinks
        have sent them already: a kill now must not lose the only record of them;
        io.sinks.spill)."""
        if len(self.pending) > self._spilled and self.spill.add(
            self.run, list(self.pending)[self._spilled :]
        ):
            self._spilled = len(self.pending)
        fresh = {
            i: held
            for i, held in self.incidents.items()
            if self._incidents_spilled.get(i) is not held
        }
        if fresh and self.spill.add_incidents(self.run, list(fresh.values())):
            self._incidents_spilled.update(fresh)

    def _store(self) -> bool:
        """Every pending event in one transaction; whether they are stored."""
        if self._old_spill:
            self._old_spill = not self._store_spill()
        rows = [event_row(e, self.run) for e in self.pending]
        placeholders = ", ".join("?" * len(COLUMNS))
        try:
            self.db.execute("BEGIN IMMEDIATE")
            if rows:  # ids from the mark, raised in this transaction: never one given before
                top = self.db.execute("SELECT MAX(id) FROM events").fetchone()[0]
                first = take(self.db, "events", len(rows), floor=int(top or 0) + 1)
                self.db.executemany(
                    f"INSERT INTO events(id, {', '.join(COLUMNS)}) VALUES (?, {placeholders})",
                    [(first + i, *row) for i, row in enumerate(rows)],
                )
            stored = dict(self.incidents)
            if stored:  # each incident's record with the step's events: one transaction
                upsert_incidents(self.db, stored.values())
            want = self._want
            if want is not None:
                self.db.execute(
                    "UPDATE id_reservations SET upto = MAX(upto, ?) WHERE run = ?",
                    (want, self.run),
                )
            self.db.execute("COMMIT")
        except sqlite3.Error as e:
            self._failed(e)
            return False
        if (self._spilled or self._incidents_spilled) and not self._old_spill:
            self.spill.clear()
        self._spilled = 0
        if want is not None:
            self.reserved, self._want = max(self.reserved or 0, want), None
        self.pending.clear()
        for i, held in stored.items():  # a change made meanwhile stays to be stored
            if self.incidents.get(i) is held:
                del self.incidents[i]
        if not self._old_spill:  # the file is gone: what still waits is in it no more
            self._incidents_spilled.clear()
        self.committed += len(rows)
        if self._error is not None and rows:
            logger.warning("%s: events stored again (%d that had waited)", self.path, len(rows))
        self._error, self._delay = None, self.retry_s
        return True

    def _failed(self, e: sqlite3.Error) -> None:
        try:
            if self.db.in_transaction:
                self.db.execute("ROLLBACK")
        except sqlite3.Error:  # the connection is broken: the next try finds out
            pass
        if self._error is None:  # once per spell, not once per frame
            logger.warning(
                "%s: cannot store events now (%s); they are kept and tried again on later frames",
                self.path,
                e,
            )
        self._error = str(e)
        self._next_try = time.monotonic() + self._delay
        self._delay = min(2 * self._delay, 2.0)

    def _close(self) -> list[Path]:
        deadline = time.monotonic() + self.close_timeout_s
        while self.pending or self._want is not None or self.incidents:
            left = deadline - time.monotonic()
            self._busy(min(max(left, 0.0), 1.0))  # a lock waited for within the deadline
            if self._store() or left <= 0:
                break
            if not self._error or "lock" not in self._error:
                time.sleep(min(0.1, max(left, 0.0)))  # another failure: no busy wait to pace it
        self._keep_waiting()
        self._ended()
        self.db.close()
        if self.pending or self.dropped:
            self.incomplete = self._unstored()
            logger.error("%s: %s", self.path, self.incomplete)
        return [self.path]

    def _ended(self) -> None:
        """Marks the run closed cleanly (all stored): a restart then knows nobody died inside."""
        if self.pending or self.dropped:
            return
        try:
            self.db.execute("UPDATE runs SET ended = ? WHERE id = ?", (time.time(), self.run))
        except sqlite3.Error as e:
            logger.warning("%s: cannot record the end of run %d: %s", self.path, self.run, e)

    def _unstored(self) -> str:
        """What could not be stored, the events kept beside the database where they can be."""
        n = len(self.pending)
        parts = []
        if n:
            parts.append(f"{n} event(s) not stored ({self._error})")
        if self.dropped:
            parts.append(
                f"{self.dropped} dropped while it was locked (buffer of {self.buffer_size} full)"
            )
        if n:
            kept = self.path.with_name(self.path.name + ".unstored.jsonl")
            try:
                with kept.open("a", encoding="utf-8") as f:  # appended: never overwritten
                    f.write("".join(json.dumps(event_record(e)) + "\n" for e in self.pending))
                self.kept_in = kept
                parts.append(f"kept in {kept}")
            except OSError as e:
                parts.append(f"and cannot be kept in {kept}: {e.strerror}")
        return "; ".join(parts)

    # -- as an alarm output (io.sinks.health.AlarmOutput) ---------------------------------

    output_name = "events_db"

    @property
    def label(self) -> str:
        return str(self.path)

    def write_changes(self, changes: Sequence[Change]) -> None:
        """The incident book's changes: their records stored with the next events, in the
        same transaction (as put_incidents)."""
        self.put_incidents([c.incident for c in changes])

    def queued(self) -> int:
        return len(self.pending)

    def figures(self) -> dict:
        """status.json's `events_db`: events stored (committed), waiting, dropped."""
        return {"committed": self.committed, "pending": len(self.pending), "dropped": self.dropped}

    def health(self) -> tuple[bool, int, str | None]:
        """(ok, waiting, reason) for the service's health (io.sinks.health): not ok while the
        last store failed (disk full, locked, read-only); waiting: the events not stored."""
        error = self._error
        return error is None, len(self.pending), error and f"cannot store events ({error})"
