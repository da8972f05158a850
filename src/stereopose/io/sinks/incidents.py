"""The incidents of the event log (`events.sqlite`, table `incidents`): each incident's current
record, its ids, and reading them back.

One row per incident (stereopose.alarms.IncidentRecord): the indexed columns a reader filters
on (state, priority, zone, person, times) and the whole record as JSON (`record`). A row is
upserted by the event sink (io.sinks.eventwriter.SqliteSink) in the transaction that stores the
step's events, so the log's incidents and events always agree, whatever moment a process is
killed. `wall_start` is the Unix time of t = 0 of the clock the record's times are on (the run
that last changed it): a wall time is wall_start + t, and a restart puts the record on its own
clock (`on_clock`).

Ids: from the log's `incidents` high-water mark (io.sinks.eventdb), reserved a block at a time
in a transaction of their own (`IncidentIds`) before the book gives one, so no id is ever
given twice, even to incidents a kill left unstored.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import sqlite3
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING
from urllib.request import pathname2url

from stereopose.alarms import IncidentRecord
from stereopose.alarms.incident import IncidentError, with_wall_times
from stereopose.io.sinks.eventdb import connect_writer, read_mark, reading, take

if TYPE_CHECKING:
    from stereopose.io.dbapi import Row

__all__ = [
    "IncidentFilters",
    "IncidentIds",
    "changes_after",
    "incident_of_event",
    "last_change",
    "on_clock",
    "open_incidents",
    "query_incidents",
    "upsert_incidents",
]


_TIMES = (
    "first_t",
    "last_t",
    "active_since",
    "cleared_at",
    "closed_at",
    "acked_at",
    "shelved_until",
)
MAX_LIMIT = 1000

logger = logging.getLogger(__name__)


def upsert_incidents(
    db: sqlite3.Connection, held: Iterable[tuple[IncidentRecord, float | None]]
) -> None:
    """Each (record, wall_start) as its incident's row, inside the caller's write
    transaction; each row written gets the next change number (`seq`, from the log's
    `incident_changes` mark: only grows, never given twice), so a reader that has every
    change up to N (the outbox's receiver) asks only for the rows with seq > N."""
    held = list(held)
    if not held:
        return
    first = take(db, "incident_changes", len(held))
    db.executemany(
        "INSERT INTO incidents(id, state, priority, occurrences, kind, zone, rule, person, "
        "camera, first_t, last_t, wall_start, record, seq) "
        "VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?) "
        "ON CONFLICT(id) DO UPDATE SET state = excluded.state, priority = excluded.priority, "
        "occurrences = excluded.occurrences, "
        "first_t = excluded.first_t, last_t = excluded.last_t, "
        "wall_start = excluded.wall_start, record = excluded.record, seq = excluded.seq",
        [
            (
                r.id,
                r.state,
                r.priority,
                r.occurrences,
                str(r.key[0]),
                r.zone,
                r.rule,
                r.person,
                r.camera,
                r.first_t,
                r.last_t,
                wall,
                json.dumps(r.to_dict()),
                first + i,
            )
            for i, (r, wall) in enumerate(held)
        ],
    )


def on_clock(rec: IncidentRecord, wall_from: float | None, wall_to: float | None) -> IncidentRecord:
    """The record's times moved from the clock starting at wall_from to that at wall_to."""
    if wall_from is None or wall_to is None:
        return rec
    shift = float(wall_from) - float(wall_to)
    return dataclasses.replace(
        rec, **{k: getattr(rec, k) + shift for k in _TIMES if getattr(rec, k) is not None}
    )


def _ro(path: Path) -> sqlite3.Connection:
    return sqlite3.connect(
        f"file:{pathname2url(str(path.resolve()))}?mode=ro", uri=True, timeout=5.0
    )


def _has_table(db: sqlite3.Connection) -> bool:
    return (
        db.execute(
            "SELECT 1 FROM sqlite_master WHERE type = 'table' AND name = 'incidents'"
        ).fetchone()
        is not None
    )


def open_incidents(db: sqlite3.Connection) -> list[tuple[IncidentRecord, float | None]]:
    """The incidents not closed, (record, wall_start), oldest first; a row that is not a
    record is skipped (it cannot be restored, and is still read by the API)."""
    if not _has_table(db):
        return []
    out = []
    for text, wall in db.execute(
        "SELECT record, wall_start FROM incidents WHERE state != 'closed' ORDER BY id"
    ):
        try:
            out.append((IncidentRecord.from_dict(json.loads(text)), wall))
        except (IncidentError, ValueError, TypeError):
            continue
    return out


@dataclass(frozen=True)
class IncidentFilters:
    """GET /api/incidents: since / until on the last time (Unix seconds)."""

    state: str | None = None
    priority: int | None = None
    zone: str | None = None
    person: int | None = None
    since: float | None = None
    until: float | None = None
    limit: int = 100


def query_incidents(path: str | Path, f: IncidentFilters) -> list[dict]:
    """Incidents of the log at path, newest first, each its record's fields with wall times
    (first_wall_t, last_wall_t, acked_wall_at, shelved_wall_until); [] without a log.
    sqlite3.Error when it cannot be read."""
    path = Path(path)
    if not path.is_file():
        return []
    where, args = [], []
    for col, value in (
        ("state", f.state),
        ("priority", f.priority),
        ("zone", f.zone),
        ("person", f.person),
    ):
        if value is not None:
            where.append(f"{col} = ?")
            args.append(value)
    if f.since is not None:
        where.append("wall_start + last_t >= ?")
        args.append(f.since)
    if f.until is not None:
        where.append("wall_start + first_t <= ?")
        args.append(f.until)
    sql = "SELECT record, wall_start FROM incidents"
    if where:
        sql += " WHERE " + " AND ".join(where)
    sql += " ORDER BY id DESC LIMIT ?"
    args.append(max(1, min(int(f.limit), MAX_LIMIT)))

    def read() -> list:
        db = _ro(path)
        try:
            return db.execute(sql, args).fetchall() if _has_table(db) else []
        finally:
            db.close()

    out = []
    for text, wall in reading(read):
        out.append(with_wall_times(json.loads(text), wall))
    return out


def changes_after(path: str | Path, seq: int, limit: int = 200) -> list[dict]:
    """The incidents whose last change is after change `seq`, in change order: each
    {"seq": its change, "incident": its record with wall times}; [] without a log or before
    any change. sqlite3.Error when it cannot be read."""
    path = Path(path)
    if not path.is_file():
        return []

    def read() -> list:
        db = _ro(path)
        try:
            if not _has_table(db) or "seq" not in _columns(db):
                return []
            return db.execute(
                "SELECT seq, record, wall_start FROM incidents WHERE seq > ? ORDER BY seq LIMIT ?",
                (int(seq), int(limit)),
            ).fetchall()
        finally:
            db.close()

    return [
        {"seq": int(n), "incident": with_wall_times(json.loads(text), wall)}
        for n, text, wall in reading(read)
    ]


def last_change(path: str | Path) -> int:
    """The last change number given to an incident row (0: none, or no log)."""
    path = Path(path)
    if not path.is_file():
        return 0

    def read() -> int:
        db = _ro(path)
        try:
            mark = read_mark(db, "incident_changes")
            if mark is not None:
                return mark - 1
            if not _has_table(db) or "seq" not in _columns(db):
                return 0
            return int(db.execute("SELECT MAX(seq) FROM incidents").fetchone()[0] or 0)
        finally:
            db.close()

    return reading(read)


def _columns(db: sqlite3.Connection) -> set[str]:
    return {r[1] for r in db.execute("PRAGMA table_info(incidents)")}


def incident_of_event(path: str | Path, event_id: int) -> int | None:
    """The incident the event `event_id` of the log belongs to (None: none, or no such)."""
    path = Path(path)
    if not path.is_file():
        return None

    def read() -> Row | None:
        db = _ro(path)
        try:
            cols = {r[1] for r in db.execute("PRAGMA table_info(events)")}
            if "incident" not in cols:
                return None
            return db.execute("SELECT incident FROM events WHERE id = ?", (event_id,)).fetchone()
        finally:
            db.close()

    row = reading(read)
    return None if row is None or row[0] is None else int(row[0])


class IncidentIds:
    """Incident ids from the log's `incidents` mark, `block` reserved at a time in their own
    committed transaction (before the book gives one: a kill skips ids, never repeats one).
    `top_up()` (each step, before the book runs) reserves the next block while half of the
    current one is left, waiting at most a moment for the log's lock; only ids run out
    wait up to busy_s. Call from one thread; `close()` at the end."""

    def __init__(self, path: str | Path, block: int = 20, busy_s: float = 5.0) -> None:
        self.path, self.block, self.busy_s = Path(path), max(2, int(block)), busy_s
        self._ranges: list[list[int]] = []  # [next, end) blocks reserved, in order
        self._db: sqlite3.Connection | None = None
        self._end = 0  # the end of the last block reserved
        self.failed = 0  # top-ups that could not reserve now (tried again next step)

    def __call__(self) -> int:
        while self._ranges and self._ranges[0][0] >= self._ranges[0][1]:
            self._ranges.pop(0)
        if not self._ranges:
            self._reserve(self.busy_s)
        r = self._ranges[0]
        r[0] += 1
        return r[0] - 1

    def left(self) -> int:
        return sum(end - nxt for nxt, end in self._ranges)

    def top_up(self, busy_s: float = 0.05) -> None:
        if self.left() >= self.block // 2:
            return
        try:
            self._reserve(busy_s)
        except sqlite3.Error as e:
            self.failed += 1
            if self.failed == 1:
                logger.warning(
                    "%s: cannot reserve incident ids now (%s); tried again", self.path, e
                )

    def _reserve(self, busy_s: float) -> None:
        if self._db is None:
            self._db = connect_writer(self.path, self.busy_s)
        db = self._db
        db.execute(f"PRAGMA busy_timeout = {max(0, int(1000 * busy_s))}")
        db.execute("BEGIN IMMEDIATE")
        try:
            top = db.execute("SELECT MAX(id) FROM incidents").fetchone()[0]
            first = take(db, "incidents", self.block, floor=max(int(top or 0) + 1, self._end))
            db.execute("COMMIT")
        except BaseException:
            if db.in_transaction:
                db.execute("ROLLBACK")
            raise
        self._end = first + self.block
        self._ranges.append([first, first + self.block])

    def close(self) -> None:
        if self._db is not None:
            self._db.close()
            self._db = None
