"""The control room store's tables (one schema for SQLite and PostgreSQL: `Dialect` turns
the few words that differ), its statements and the rows it writes from what sites send."""

from __future__ import annotations

import json
import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from stereopose.io.dbapi import Connection, Cursor

SCHEMA = """
CREATE TABLE IF NOT EXISTS sites (
    site TEXT PRIMARY KEY,
    mark INTEGER NOT NULL DEFAULT 0,   -- events stored with nothing missing up to this id
    state TEXT NOT NULL DEFAULT 'unknown',  -- live, offline, degraded, unknown
    last_seen REAL,                    -- Unix time of its last message
    health TEXT,                       -- its latest summary (JSON, from its heartbeat)
    incident_mark INTEGER NOT NULL DEFAULT 0  -- incident changes stored up to this number
);
CREATE TABLE IF NOT EXISTS events (
    site TEXT NOT NULL,
    id INTEGER NOT NULL,               -- the site's event log id
    wall_t REAL,
    type TEXT,
    zone TEXT,
    person INTEGER,
    incident INTEGER,
    priority INTEGER,
    stored_at REAL NOT NULL,
    record TEXT NOT NULL,              -- the event as the site sent it (JSON)
    PRIMARY KEY (site, id)
) WITHOUT ROWID;
CREATE TABLE IF NOT EXISTS incidents (
    site TEXT NOT NULL,
    id INTEGER NOT NULL,               -- the site's incident id
    seq INTEGER NOT NULL,              -- the site's change number of this record
    state TEXT,                        -- active, acknowledged, cleared, closed
    priority INTEGER,
    zone TEXT,
    person INTEGER,
    last_wall_t REAL,
    stored_at REAL NOT NULL,
    record TEXT NOT NULL,              -- the incident's record as the site sent it (JSON)
    PRIMARY KEY (site, id)
) WITHOUT ROWID;
CREATE INDEX IF NOT EXISTS incidents_state ON incidents(state);
CREATE TABLE IF NOT EXISTS commands (  -- acknowledgements asked of sites
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    site TEXT NOT NULL,
    incident INTEGER NOT NULL,
    asked_by TEXT NOT NULL,            -- the control room's user
    asked_at REAL NOT NULL,
    done_at REAL,                      -- when the site answered
    result TEXT                        -- acknowledged, already, unknown, unavailable
);
CREATE INDEX IF NOT EXISTS commands_pending ON commands(done_at);
CREATE TABLE IF NOT EXISTS room_incidents (  -- raised by the control room about a site
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    site TEXT NOT NULL,
    kind TEXT NOT NULL,                -- site_offline, site_clock
    priority INTEGER NOT NULL,
    state TEXT NOT NULL,               -- active, acknowledged, cleared, closed
    raised_at REAL NOT NULL,
    cleared_at REAL,
    acked_by TEXT,
    acked_at REAL,
    detail TEXT
);
CREATE INDEX IF NOT EXISTS room_incidents_open ON room_incidents(site, kind, state);
"""
# columns an earlier version's store lacks: (table, column, declaration)
ADDED = (("sites", "incident_mark", "INTEGER NOT NULL DEFAULT 0"),)
SCHEMA_LOCK = 0x5354_4552_4551  # PostgreSQL advisory lock held while the tables are made


@dataclass(frozen=True)
class SiteRow:
    site: str
    mark: int
    state: str
    last_seen: float | None
    health: dict | None
    events: int = 0  # events stored


class Dialect:
    """The statements as written here (SQLite's `?` and `INSERT OR IGNORE`, `GREATEST` for the
    larger of two values) in the store's own words."""

    def __init__(self, postgres: bool) -> None:
        self.postgres = postgres

    def q(self, sql: str) -> str:
        if not self.postgres:
            return sql.replace("GREATEST(", "MAX(")
        if sql.startswith("INSERT OR IGNORE INTO"):
            sql = sql.replace("INSERT OR IGNORE INTO", "INSERT INTO", 1) + " ON CONFLICT DO NOTHING"
        return sql.replace("?", "%s")

    def schema(self) -> list[str]:
        text = SCHEMA
        if self.postgres:
            text = text.replace("INTEGER PRIMARY KEY AUTOINCREMENT", "BIGSERIAL PRIMARY KEY")
            text = re.sub(r"\bINTEGER\b", "BIGINT", text)
            text = re.sub(r"\bREAL\b", "DOUBLE PRECISION", text)
            text = text.replace(" WITHOUT ROWID", "")
        text = re.sub(r"--[^\n]*", "", text)
        return [st.strip() for st in text.split(";") if st.strip()]


class Run:
    """Statements on one connection in the store's dialect: run(sql, args) -> cursor,
    run.many(sql, rows) -> the rows changed."""

    def __init__(self, db: Connection, dialect: Dialect) -> None:
        self.db, self.dialect = db, dialect

    def __call__(self, sql: str, args: Sequence = ()) -> Cursor:
        return self.db.execute(self.dialect.q(sql), args)

    def many(self, sql: str, rows: Sequence[Sequence]) -> int:
        if not rows:
            return 0
        cur = self.db.cursor()
        cur.executemany(self.dialect.q(sql), rows)
        return max(0, cur.rowcount)


PUT_EVENT = (
    "INSERT OR IGNORE INTO events(site, id, wall_t, type, zone, person, incident, "
    "priority, stored_at, record) VALUES (?,?,?,?,?,?,?,?,?,?)"
)
PUT_CHANGE = (
    "INSERT INTO incidents(site, id, seq, state, priority, zone, person, last_wall_t, "
    "stored_at, record) VALUES (?,?,?,?,?,?,?,?,?,?) ON CONFLICT(site, id) DO UPDATE "
    "SET seq = excluded.seq, state = excluded.state, priority = excluded.priority, "
    "zone = excluded.zone, person = excluded.person, last_wall_t = "
    "excluded.last_wall_t, stored_at = excluded.stored_at, record = excluded.record "
    "WHERE excluded.seq > incidents.seq"
)
RAISE_MARK = (
    "INSERT INTO sites(site, mark, last_seen) VALUES (?, ?, ?) ON CONFLICT(site) DO "
    "UPDATE SET mark = GREATEST(sites.mark, excluded.mark), last_seen = "
    "excluded.last_seen"
)
RAISE_INCIDENT_MARK = (
    "INSERT INTO sites(site, incident_mark, last_seen) VALUES (?, ?, ?) ON "
    "CONFLICT(site) DO UPDATE SET incident_mark = GREATEST("
    "sites.incident_mark, excluded.incident_mark), last_seen = "
    "excluded.last_seen"
)


def event_row(site: str, e: dict, now: float) -> tuple:
    return (
        site,
        int(e["id"]),
        _num(e.get("wall_t")),
        _text(e.get("type")),
        _text(e.get("zone")),
        _int(e.get("person")),
        _int(e.get("incident")),
        _int(e.get("priority")),
        now,
        json.dumps(e, separators=(",", ":")),
    )


def change_row(site: str, c: dict, now: float) -> tuple:
    rec = c["incident"]
    return (
        site,
        int(rec["id"]),
        int(c["seq"]),
        _text(rec.get("state")),
        _int(rec.get("priority")),
        _text(rec.get("zone")),
        _int(rec.get("person")),
        _num(rec.get("last_wall_t")),
        now,
        json.dumps(rec, separators=(",", ":")),
    )


ROOM_COLUMNS = "id, site, kind, priority, state, raised_at, cleared_at, acked_by, acked_at, detail"


def room_record(row: tuple) -> dict:
    i, site, kind, priority, state, raised, cleared, by, at, detail = row
    return {
        "source": "control_room",
        "site": site,
        "id": i,
        "kind": kind,
        "priority": priority,
        "state": state,
        "first_wall_t": raised,
        "last_wall_t": cleared or raised,
        "cleared_wall_at": cleared,
        "acked_by": by,
        "acked_wall_at": at,
        "detail": detail,
        "occurrences": 1,
    }


def _num(v: object) -> float | None:
    return float(v) if isinstance(v, int | float) and not isinstance(v, bool) else None


def _int(v: object) -> int | None:
    return int(v) if isinstance(v, int) and not isinstance(v, bool) else None


def _text(v: object) -> str | None:
    return v if isinstance(v, str) else None


def of_sites(site: str | None, sites: Iterable[str] | None) -> tuple[list[str], list]:
    """The conditions (and their values) for rows of `site`, and of `sites` when given."""
    where, args = [], []
    if site is not None:
        where.append("site = ?")
        args.append(site)
    if sites is not None:
        allowed = sorted(set(sites))
        where.append(f"site IN ({','.join('?' * len(allowed))})" if allowed else "FALSE")
        args += allowed
    return where, args
