"""The event log's SQLite file: its whole schema (every table once, the upgrades of an earlier
version's log: `create_schema`), one way to open it for writing, and its high-water marks.

Every connection that writes `events.sqlite` (the event sink, the person-id reservations,
the acknowledgements, retention) is opened by `connect_writer`, so they all agree: WAL
journal, synchronous=NORMAL, a busy timeout; and each raises the high-water marks first.

High-water marks (table `counters`, one row per kind of id): `next` is the first id not
given yet; every id of that kind ever given is below it. An id is taken (`take`) inside the
write transaction that stores what it names, so the raised mark and the row commit together
and no id can be seen anywhere before its mark is durable; nothing ever lowers a mark (the
retention deletes rows, never counters). So ids strictly increase for the life of the log,
whatever was deleted and whenever a process was killed. Kinds: `events` (events.id),
`persons` (person ids, reserved ahead by site.person_ids); further kinds (incidents) are
added the same way, with their seed in SEEDS.

A log of an earlier version (no `counters`, or rows written by a version that did not raise
them) is brought up to date by `raise_marks` at every writer's open: each mark is raised
above the largest id its kind's rows and any row naming one (an acknowledgement names an
event) hold. Ids that an earlier version gave and deleted, with nothing left naming them,
cannot be known: the marks start above what is left.
"""

from __future__ import annotations

import sqlite3
import time
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar
from urllib.request import pathname2url

__all__ = [
    "COUNTERS_SCHEMA",
    "SCHEMA",
    "SEEDS",
    "connect_writer",
    "create_schema",
    "raise_marks",
    "read_mark",
    "reading",
    "table_columns",
    "take",
    "transient",
]

COUNTERS_SCHEMA = """
CREATE TABLE IF NOT EXISTS counters (
    name TEXT PRIMARY KEY,
    next INTEGER NOT NULL            -- the first id not given; every id given is below it
);
"""

# The whole schema of the log, every table once: the runs, the events, the person-id
# reservations of earlier versions, the high-water marks (COUNTERS_SCHEMA), the incidents and
# the acknowledgements. `create_schema` makes what is missing and brings an earlier version's
# log up to date; every writer calls it at its open.
EVENTS_SCHEMA = """
CREATE TABLE IF NOT EXISTS runs (
    id INTEGER PRIMARY KEY,
    started REAL NOT NULL,           -- unix time
    site TEXT,
    source TEXT,
    ended REAL,                      -- unix time of a clean close; NULL: still running or killed
    wall_start REAL                  -- unix time of t = 0 (serve); NULL: not recorded
);
CREATE TABLE IF NOT EXISTS events (
    id INTEGER PRIMARY KEY,
    run INTEGER NOT NULL REFERENCES runs(id),
    t REAL NOT NULL,
    frame INTEGER NOT NULL,
    person INTEGER NOT NULL,
    zone TEXT NOT NULL,
    kind TEXT NOT NULL,
    type TEXT NOT NULL,
    onset_t REAL,
    joint TEXT,
    distance_m REAL,
    duration_s REAL,
    x REAL,
    y REAL,
    allowed INTEGER NOT NULL DEFAULT 0,
    lost INTEGER NOT NULL DEFAULT 0,
    restart INTEGER NOT NULL DEFAULT 0,
    camera TEXT,
    reprojection_px REAL,
    baseline_px REAL,
    rule TEXT,
    posture TEXT,
    nearest_m REAL,
    facing_deg REAL,
    failed TEXT,
    height_m REAL,
    speed_m_s REAL
);
CREATE TABLE IF NOT EXISTS id_reservations (
    run INTEGER PRIMARY KEY REFERENCES runs(id),
    upto INTEGER NOT NULL            -- every person id this run gave is below it
);
CREATE INDEX IF NOT EXISTS events_person ON events(person);
CREATE INDEX IF NOT EXISTS events_zone ON events(zone);
CREATE INDEX IF NOT EXISTS events_t ON events(t);
"""
INCIDENTS_SCHEMA = """
CREATE TABLE IF NOT EXISTS incidents (
    id INTEGER PRIMARY KEY,
    state TEXT NOT NULL,             -- active, acknowledged, cleared, closed
    priority INTEGER NOT NULL,       -- 1 critical .. 4 low
    occurrences INTEGER NOT NULL,
    kind TEXT NOT NULL,              -- the hazard's kind: zone, rule, camera, ...
    zone TEXT,
    rule TEXT,
    person INTEGER,
    camera TEXT,
    first_t REAL NOT NULL,           -- seconds on the clock of wall_start
    last_t REAL NOT NULL,
    wall_start REAL,                 -- Unix time of t = 0 of the record's times
    record TEXT NOT NULL,            -- IncidentRecord.to_dict() as JSON
    seq INTEGER                      -- the log's change number of the row's last write
);
CREATE INDEX IF NOT EXISTS incidents_state ON incidents(state);
CREATE INDEX IF NOT EXISTS incidents_zone ON incidents(zone);
CREATE INDEX IF NOT EXISTS incidents_person ON incidents(person);
"""
ACKS_SCHEMA = """
CREATE TABLE IF NOT EXISTS acks (
    event INTEGER PRIMARY KEY REFERENCES events(id),
    by TEXT NOT NULL,
    at REAL NOT NULL                 -- unix time
);
"""
SCHEMA = EVENTS_SCHEMA + COUNTERS_SCHEMA + INCIDENTS_SCHEMA + ACKS_SCHEMA
# after the upgrade has added `seq` to an earlier version's incidents table
INCIDENTS_SEQ_INDEX = "CREATE INDEX IF NOT EXISTS incidents_seq ON incidents(seq)"

# columns later versions added, for a log an earlier version created (table, column, SQL type)
ADDED_COLUMNS = (
    ("runs", "ended", "REAL"),
    ("runs", "wall_start", "REAL"),
    ("events", "restart", "INTEGER NOT NULL DEFAULT 0"),
    ("events", "camera", "TEXT"),
    ("incidents", "seq", "INTEGER"),
    ("events", "reprojection_px", "REAL"),
    ("events", "baseline_px", "REAL"),
    ("events", "rule", "TEXT"),
    ("events", "posture", "TEXT"),
    ("events", "nearest_m", "REAL"),
    ("events", "facing_deg", "REAL"),
    ("events", "failed", "TEXT"),
    ("events", "height_m", "REAL"),
    ("events", "speed_m_s", "REAL"),
    ("events", "incident", "INTEGER"),
    ("events", "priority", "INTEGER"),
    ("events", "ticket", "TEXT"),
    ("events", "step", "TEXT"),
    ("events", "result", "TEXT"),
    ("events", "source", "TEXT"),
)


def table_columns(db: sqlite3.Connection, table: str) -> set[str]:
    """The column names of `table` (none: no such table)."""
    return {row[1] for row in db.execute(f"PRAGMA table_info({table})")}


def _upgrade(db: sqlite3.Connection) -> None:
    """Adds the columns a log written by an earlier version lacks (its rows keep their values;
    the new columns read as NULL, or 0 for restart)."""
    for table, column, decl in ADDED_COLUMNS:
        if column in table_columns(db, table):
            continue
        try:
            db.execute(f"ALTER TABLE {table} ADD COLUMN {column} {decl}")
        except sqlite3.OperationalError as e:
            if "duplicate column" not in str(e):  # another process added it first: fine
                raise


def create_schema(db: sqlite3.Connection) -> None:
    """Every table and index of the log made where missing, and the columns a log of an
    earlier version lacks added."""
    db.executescript(SCHEMA)
    _upgrade(db)
    db.execute(INCIDENTS_SEQ_INDEX)


# per kind, (table, SQL giving one above the largest id held by that table): the floor of
# its mark at every writer's open; a table missing from a log is skipped
SEEDS: dict[str, tuple[tuple[str, str], ...]] = {
    "events": (
        ("events", "SELECT MAX(id) + 1 FROM events"),
        ("acks", "SELECT MAX(event) + 1 FROM acks"),
    ),
    "persons": (("events", "SELECT MAX(person) + 1 FROM events"),),
    # an incident's id is in the incidents table before any event names it (io.sinks.incidents)
    "incidents": (("incidents", "SELECT MAX(id) + 1 FROM incidents"),),
    # the change number of an incident row's last write (io.sinks.incidents.upsert_incidents)
    "incident_changes": (("incidents", "SELECT MAX(seq) + 1 FROM incidents"),),
}
# the same, only as the mark is made (an earlier version's reservations; SqliteSink still
# records its own there, below the mark, which must not push the mark a block up each run)
FIRST_SEEDS: dict[str, tuple[tuple[str, str], ...]] = {
    "persons": (("id_reservations", "SELECT MAX(upto) FROM id_reservations"),),
}

# what a reader may see for a moment while writers of a WAL log start, end or check-point:
# worth one more try (an error that stays is reported as it is)
_TRANSIENT = ("locked", "busy", "malformed", "disk i/o error")

T = TypeVar("T")


def transient(e: sqlite3.Error) -> bool:
    """Whether e may pass on a second try (a lock, a WAL being recovered by another process)."""
    text = str(e).lower()
    return any(word in text for word in _TRANSIENT)


def reading(read: Callable[[], T], tries: int = 3, pause_s: float = 0.05) -> T:
    """read(), tried again (at most `tries` times) after a transient error; the last error
    raised. For read-only readers: a reader that opens the log while another process recovers
    its WAL after a kill may see an error for a moment that a new connection does not."""
    for n in range(tries):
        try:
            return read()
        except sqlite3.DatabaseError as e:
            if n == tries - 1 or not transient(e):
                raise
            time.sleep(pause_s * (n + 1))
    raise AssertionError("unreachable")


def connect_writer(path: str | Path, busy_s: float, *, create: bool = False) -> sqlite3.Connection:
    """A connection that may write the log at path: autocommit (transactions are explicit),
    WAL, synchronous=NORMAL (a transaction committed survives the process killed; WAL keeps
    the file consistent whatever moment), busy_s the longest a lock is waited for; the marks
    raised (when the log has its tables). create: the file may be made (the event sink);
    otherwise an existing log is required (mode=rw). sqlite3.Error when it cannot."""
    target: str | Path = Path(path)
    if not create:  # an existing file only: never an empty log made beside a moved one
        target = f"file:{pathname2url(str(Path(path).resolve()))}?mode=rw"
    db = sqlite3.connect(
        target, uri=not create, isolation_level=None, timeout=busy_s, check_same_thread=False
    )
    try:
        db.execute(f"PRAGMA busy_timeout = {max(0, int(1000 * busy_s))}")
        if db.execute("PRAGMA journal_mode").fetchone()[0].lower() != "wal":
            db.execute("PRAGMA journal_mode=WAL")
        db.execute("PRAGMA synchronous=NORMAL")
        raise_marks(db)
    except BaseException:
        db.close()
        raise
    return db


def _tables(db: sqlite3.Connection) -> set[str]:
    return {r[0] for r in db.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}


def _floors(db: sqlite3.Connection) -> dict[str, int]:
    """Per mark, the least value it may have: one above the ids its tables hold."""
    tables = _tables(db)
    have = (
        {n for (n,) in db.execute("SELECT name FROM counters")} if "counters" in tables else set()
    )
    floors = {}
    for name, seeds in SEEDS.items():
        floor = 1
        for table, sql in seeds + (() if name in have else FIRST_SEEDS.get(name, ())):
            if table in tables:
                try:
                    floor = max(floor, int(db.execute(sql).fetchone()[0] or 0))
                except sqlite3.OperationalError as e:  # an earlier version's table: no column
                    if "no such column" not in str(e):
                        raise
        floors[name] = floor
    return floors


def _marks(db: sqlite3.Connection) -> dict[str, int]:
    if "counters" not in _tables(db):
        return {}
    return {n: int(v) for n, v in db.execute("SELECT name, next FROM counters")}


def raise_marks(db: sqlite3.Connection) -> None:
    """Each mark of SEEDS raised above the ids its tables hold (created at the first id);
    nothing when the log has no events table yet. Read first: a short write transaction only
    when a mark is missing or behind (an earlier version's log, or rows it wrote since)."""
    if "events" not in _tables(db):
        return
    marks = _marks(db)
    if all(marks.get(name, 0) >= floor for name, floor in _floors(db).items()):
        return
    db.execute("BEGIN IMMEDIATE")
    try:
        db.execute(COUNTERS_SCHEMA.strip().rstrip(";"))
        for name, floor in _floors(db).items():  # again, under the write lock
            db.execute(
                "INSERT INTO counters(name, next) VALUES (?, ?) ON CONFLICT(name) DO "
                "UPDATE SET next = MAX(next, excluded.next)",
                (name, floor),
            )
        db.execute("COMMIT")
    except BaseException:
        if db.in_transaction:
            db.execute("ROLLBACK")
        raise


def read_mark(db: sqlite3.Connection, name: str) -> int | None:
    """The mark `name` (the first id not given), None when the log has none."""
    if "counters" not in _tables(db):
        return None
    row = db.execute("SELECT next FROM counters WHERE name = ?", (name,)).fetchone()
    return None if row is None else int(row[0])


def take(db: sqlite3.Connection, name: str, n: int, floor: int = 1) -> int:
    """The first of n ids of kind `name`, the mark raised past them; inside a write
    transaction of db (BEGIN IMMEDIATE), so it commits with what the ids name. floor: the
    least first id the caller may take (its own earlier ones, rows of another writer)."""
    row = db.execute("SELECT next FROM counters WHERE name = ?", (name,)).fetchone()
    first = max(floor, int(row[0]) if row is not None else 1)
    db.execute(
        "INSERT INTO counters(name, next) VALUES (?, ?) ON CONFLICT(name) DO "
        "UPDATE SET next = MAX(next, excluded.next)",
        (name, first + n),
    )
    return first
