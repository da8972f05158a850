"""The control room's store: its sites and every site's events, each (site, id) once.

SQLite (WAL, one writer: the ingest's thread; readers open their own read-only connections)
in the control room's output folder (`control.sqlite` by default). The events table's primary
key is (site, id): an event sent twice (a QoS 1 resend, a replay, a bridge's duplicates) is
stored once, and the duplicate counted. A site's mark (the highest id stored with nothing
missing before it, service.outbox's protocol) is kept with the site, in the same transaction
as the events that raise it, so a control room killed at any moment restarts with a mark
that only names what it holds.
"""

from __future__ import annotations

import json
import sqlite3
import threading
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from urllib.request import pathname2url

from stereopose.errors import StereoposeError

__all__ = ["ControlStore", "SiteRow", "StoreError"]

SCHEMA = """
CREATE TABLE IF NOT EXISTS sites (
    site TEXT PRIMARY KEY,
    mark INTEGER NOT NULL DEFAULT 0,   -- events stored with nothing missing up to this id
    state TEXT NOT NULL DEFAULT 'unknown',  -- live, offline, degraded, unknown
    last_seen REAL,                    -- Unix time of its last message
    health TEXT                        -- its latest health message (JSON), if any
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
"""
MAX_LIMIT = 1000


class StoreError(StereoposeError):
    """The control room's store cannot be opened, read or written."""


@dataclass(frozen=True)
class SiteRow:
    site: str
    mark: int
    state: str
    last_seen: float | None
    health: dict | None
    events: int = 0  # events stored


class ControlStore:
    """The store at `path` (made when missing). Writes (`put_events`, `set_site`) come from
    one thread; `events`, `sites` open a read-only connection per call."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self._lock = threading.Lock()
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self.db = sqlite3.connect(self.path, timeout=5.0, check_same_thread=False)
            self.db.execute("PRAGMA journal_mode = WAL")
            self.db.execute("PRAGMA synchronous = NORMAL")
            self.db.executescript(SCHEMA)
            self.db.commit()
        except (sqlite3.Error, OSError) as e:
            raise StoreError(f"{self.path}: cannot open the control room's store: {e}") from None
        self.duplicates = 0
        self.stored = 0

    # --- writes ----------------------------------------------------------------------------

    def put_events(self, site: str, events: Sequence[dict], mark: int, now: float) -> int:
        """Store a site's events (each (site, id) once) and its new mark, in one transaction;
        the number newly stored."""
        rows = [(site, int(e["id"]), _num(e.get("wall_t")), _text(e.get("type")),
                 _text(e.get("zone")), _int(e.get("person")), _int(e.get("incident")),
                 _int(e.get("priority")), now, json.dumps(e, separators=(",", ":")))
                for e in events]  # fmt: skip
        with self._lock:
            try:
                before = self.db.total_changes
                self.db.executemany(
                    "INSERT OR IGNORE INTO events(site, id, wall_t, type, zone, person, "
                    "incident, priority, stored_at, record) VALUES (?,?,?,?,?,?,?,?,?,?)",
                    rows,
                )
                new = self.db.total_changes - before
                self.db.execute(
                    "INSERT INTO sites(site, mark, last_seen) VALUES (?, ?, ?) ON CONFLICT(site) "
                    "DO UPDATE SET mark = MAX(mark, excluded.mark), last_seen = excluded.last_seen",
                    (site, mark, now),
                )
                self.db.commit()
            except sqlite3.Error as e:
                self.db.rollback()
                raise StoreError(f"{self.path}: cannot store {len(rows)} event(s) of site "
                                 f"{site!r}: {e}") from None  # fmt: skip
        self.stored += new
        self.duplicates += len(rows) - new
        return new

    def set_site(self, site: str, *, state: str | None = None, last_seen: float | None = None,
                 health: dict | None = None) -> None:  # fmt: skip
        with self._lock:
            try:
                self.db.execute("INSERT OR IGNORE INTO sites(site) VALUES (?)", (site,))
                if state is not None:
                    self.db.execute("UPDATE sites SET state = ? WHERE site = ?", (state, site))
                if last_seen is not None:
                    self.db.execute("UPDATE sites SET last_seen = MAX(COALESCE(last_seen, 0), ?)"
                                    " WHERE site = ?", (last_seen, site))  # fmt: skip
                if health is not None:
                    self.db.execute("UPDATE sites SET health = ? WHERE site = ?",
                                    (json.dumps(health), site))  # fmt: skip
                self.db.commit()
            except sqlite3.Error as e:
                self.db.rollback()
                raise StoreError(f"{self.path}: cannot update site {site!r}: {e}") from None

    def marks(self) -> dict[str, int]:
        with self._lock:
            return dict(self.db.execute("SELECT site, mark FROM sites").fetchall())

    # --- reads -----------------------------------------------------------------------------

    def _reader(self) -> sqlite3.Connection:
        try:
            db = sqlite3.connect(f"file:{pathname2url(str(self.path.resolve()))}?mode=ro",
                                 uri=True, timeout=2.0)  # fmt: skip
            db.execute("PRAGMA busy_timeout = 2000")
            return db
        except sqlite3.Error as e:
            raise StoreError(f"{self.path}: cannot read the control room's store: {e}") from None

    def sites(self, only: Iterable[str] | None = None) -> list[SiteRow]:
        db = self._reader()
        try:
            rows = db.execute("SELECT s.site, s.mark, s.state, s.last_seen, s.health, "
                              "(SELECT COUNT(*) FROM events e WHERE e.site = s.site) "
                              "FROM sites s ORDER BY s.site").fetchall()  # fmt: skip
        except sqlite3.Error as e:
            raise StoreError(f"{self.path}: cannot read the sites: {e}") from None
        finally:
            db.close()
        keep = None if only is None else set(only)
        return [SiteRow(s, m, st, seen, json.loads(h) if h else None, n)
                for s, m, st, seen, h, n in rows if keep is None or s in keep]  # fmt: skip

    def events(self, site: str | None = None, after_id: int = 0, limit: int = 100,
               sites: Iterable[str] | None = None) -> list[dict]:  # fmt: skip
        """Events in (site, id) order: of `site` after `after_id`, or of every site (of
        `sites` when given); at most `limit` (<= MAX_LIMIT)."""
        limit = max(1, min(int(limit), MAX_LIMIT))
        where, args = ["id > ?"], [int(after_id)]
        if site is not None:
            where.append("site = ?")
            args.append(site)
        if sites is not None:
            allowed = sorted(set(sites))
            where.append(f"site IN ({','.join('?' * len(allowed))})" if allowed else "0")
            args += allowed
        db = self._reader()
        try:
            rows = db.execute(f"SELECT site, record FROM events WHERE {' AND '.join(where)} "
                              "ORDER BY site, id LIMIT ?", [*args, limit]).fetchall()  # fmt: skip
        except sqlite3.Error as e:
            raise StoreError(f"{self.path}: cannot read the events: {e}") from None
        finally:
            db.close()
        return [{**json.loads(rec), "site": s} for s, rec in rows]

    def close(self) -> None:
        with self._lock:
            self.db.close()


def _num(v: object) -> float | None:
    return float(v) if isinstance(v, int | float) and not isinstance(v, bool) else None


def _int(v: object) -> int | None:
    return int(v) if isinstance(v, int) and not isinstance(v, bool) else None


def _text(v: object) -> str | None:
    return v if isinstance(v, str) else None
