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
    by TEXT NOT NULL,                  -- the control room's user
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
OPEN_STATES = ("active", "acknowledged", "cleared")
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
            for table, column, decl in ADDED:
                have = {r[1] for r in self.db.execute(f"PRAGMA table_info({table})")}
                if column not in have:
                    self.db.execute(f"ALTER TABLE {table} ADD COLUMN {column} {decl}")
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

    def put_incidents(self, site: str, changes: Sequence[dict], mark: int, now: float) -> int:
        """Store a site's incident changes ({"seq", "incident": record}; a record replaces the
        stored one only when its seq is newer) and its new incidents mark, in one
        transaction; the number of records written."""
        rows = []
        for c in changes:
            rec = c["incident"]
            rows.append((site, int(rec["id"]), int(c["seq"]), _text(rec.get("state")),
                         _int(rec.get("priority")), _text(rec.get("zone")),
                         _int(rec.get("person")), _num(rec.get("last_wall_t")), now,
                         json.dumps(rec, separators=(",", ":"))))  # fmt: skip
        with self._lock:
            try:
                before = self.db.total_changes
                self.db.executemany(
                    "INSERT INTO incidents(site, id, seq, state, priority, zone, person, "
                    "last_wall_t, stored_at, record) VALUES (?,?,?,?,?,?,?,?,?,?) "
                    "ON CONFLICT(site, id) DO UPDATE SET seq = excluded.seq, "
                    "state = excluded.state, priority = excluded.priority, "
                    "zone = excluded.zone, person = excluded.person, "
                    "last_wall_t = excluded.last_wall_t, stored_at = excluded.stored_at, "
                    "record = excluded.record WHERE excluded.seq > incidents.seq",
                    rows,
                )
                new = self.db.total_changes - before
                self.db.execute(
                    "INSERT INTO sites(site, incident_mark, last_seen) VALUES (?, ?, ?) "
                    "ON CONFLICT(site) DO UPDATE SET incident_mark = MAX(incident_mark, "
                    "excluded.incident_mark), last_seen = excluded.last_seen",
                    (site, mark, now),
                )
                self.db.commit()
            except sqlite3.Error as e:
                self.db.rollback()
                raise StoreError(f"{self.path}: cannot store {len(rows)} incident change(s) "
                                 f"of site {site!r}: {e}") from None  # fmt: skip
        return new

    def add_command(self, site: str, incident: int, by: str, now: float) -> int:
        """An acknowledgement to ask of `site`; its command id."""
        with self._lock:
            try:
                cur = self.db.execute("INSERT INTO commands(site, incident, by, asked_at) "
                                      "VALUES (?, ?, ?, ?)", (site, incident, by, now))  # fmt: skip
                self.db.commit()
            except sqlite3.Error as e:
                self.db.rollback()
                raise StoreError(f"{self.path}: cannot store the acknowledgement: {e}") from None
        return int(cur.lastrowid)

    def finish_command(self, command: int, result: str, now: float) -> bool:
        """The site's answer to `command`; whether it was still waiting."""
        with self._lock:
            try:
                cur = self.db.execute("UPDATE commands SET done_at = ?, result = ? WHERE id = ? "
                                      "AND done_at IS NULL", (now, result, command))  # fmt: skip
                self.db.commit()
            except sqlite3.Error as e:
                self.db.rollback()
                raise StoreError(f"{self.path}: cannot store a site's answer: {e}") from None
        return cur.rowcount > 0

    def pending_commands(self) -> list[tuple[int, str, int, str]]:
        """(command, site, incident, by) not answered yet, oldest first."""
        with self._lock:
            return self.db.execute("SELECT id, site, incident, by FROM commands WHERE done_at "
                                   "IS NULL ORDER BY id").fetchall()  # fmt: skip

    def raise_room_incident(self, site: str, kind: str, priority: int, detail: str,
                            now: float) -> int | None:  # fmt: skip
        """A control-room incident of `kind` about `site`, unless one is active already; its
        id (None: one was)."""
        with self._lock:
            try:
                if self.db.execute("SELECT 1 FROM room_incidents WHERE site = ? AND kind = ? "
                                   "AND state IN ('active', 'acknowledged')",
                                   (site, kind)).fetchone():  # fmt: skip
                    return None
                cur = self.db.execute(
                    "INSERT INTO room_incidents(site, kind, priority, state, raised_at, detail) "
                    "VALUES (?, ?, ?, 'active', ?, ?)",
                    (site, kind, priority, now, detail),
                )
                self.db.commit()
            except sqlite3.Error as e:
                self.db.rollback()
                raise StoreError(f"{self.path}: cannot raise an incident: {e}") from None
        return int(cur.lastrowid)

    def clear_room_incidents(self, site: str, kind: str, now: float) -> int:
        """The active incidents of `kind` about `site` cleared (closed when acknowledged)."""
        with self._lock:
            try:
                cur = self.db.execute(
                    "UPDATE room_incidents SET cleared_at = ?, state = CASE state WHEN "
                    "'acknowledged' THEN 'closed' ELSE 'cleared' END WHERE site = ? AND "
                    "kind = ? AND state IN ('active', 'acknowledged')",
                    (now, site, kind),
                )
                self.db.commit()
            except sqlite3.Error as e:
                self.db.rollback()
                raise StoreError(f"{self.path}: cannot clear an incident: {e}") from None
        return cur.rowcount

    def ack_room_incident(self, incident: int, by: str, now: float) -> dict | None:
        """Acknowledge a control-room incident (a cleared one closes); its row, None when
        there is none with that id."""
        with self._lock:
            try:
                self.db.execute(
                    "UPDATE room_incidents SET acked_by = ?, acked_at = ?, state = CASE state "
                    "WHEN 'active' THEN 'acknowledged' WHEN 'cleared' THEN 'closed' ELSE state "
                    "END WHERE id = ? AND acked_by IS NULL",
                    (by, now, incident),
                )
                self.db.commit()
                row = self.db.execute(f"SELECT {_ROOM_COLUMNS} FROM room_incidents WHERE id = ?",
                                      (incident,)).fetchone()  # fmt: skip
            except sqlite3.Error as e:
                self.db.rollback()
                raise StoreError(f"{self.path}: cannot acknowledge an incident: {e}") from None
        return None if row is None else _room_incident(row)

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

    def set_summaries(self, summaries: dict[str, dict]) -> None:
        """Each site's latest summary (its heartbeat's status, cameras, people), at once."""
        with self._lock:
            try:
                self.db.executemany(
                    "INSERT INTO sites(site, health) VALUES (?, ?) ON CONFLICT(site) DO UPDATE "
                    "SET health = excluded.health",
                    [(site, json.dumps(v)) for site, v in summaries.items()],
                )
                self.db.commit()
            except sqlite3.Error as e:
                self.db.rollback()
                raise StoreError(f"{self.path}: cannot update the sites: {e}") from None

    def marks(self) -> dict[str, int]:
        with self._lock:
            return dict(self.db.execute("SELECT site, mark FROM sites").fetchall())

    def incident_marks(self) -> dict[str, int]:
        with self._lock:
            return dict(self.db.execute("SELECT site, incident_mark FROM sites").fetchall())

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

    def incidents(
        self,
        site: str | None = None,
        state: str | None = None,
        sites: Iterable[str] | None = None,
        limit: int = 100,
    ) -> list[dict]:
        """The sites' incidents (newest change first) with the control room's own
        (`"source": "control_room"`): of `site`, in `state` ("open": not closed), of `sites`
        when given; at most `limit` of each kind. Each site incident carries the
        acknowledgements asked of its site and not answered yet (`ack_pending`)."""
        limit = max(1, min(int(limit), MAX_LIMIT))
        where, args = [], []
        if site is not None:
            where.append("site = ?")
            args.append(site)
        if state == "open":
            where.append("state IN ('active', 'acknowledged', 'cleared')")
        elif state is not None:
            where.append("state = ?")
            args.append(state)
        if sites is not None:
            allowed = sorted(set(sites))
            where.append(f"site IN ({','.join('?' * len(allowed))})" if allowed else "0")
            args += allowed
        cond = f" WHERE {' AND '.join(where)}" if where else ""
        db = self._reader()
        try:
            rows = db.execute(
                f"SELECT site, seq, record FROM incidents{cond} ORDER BY "
                "stored_at DESC, site, id DESC LIMIT ?",
                [*args, limit],
            ).fetchall()
            room = db.execute(f"SELECT {_ROOM_COLUMNS} FROM room_incidents{cond} ORDER BY id "
                              "DESC LIMIT ?", [*args, limit]).fetchall()  # fmt: skip
            pending = db.execute("SELECT site, incident, by, asked_at FROM commands WHERE "
                                 "done_at IS NULL").fetchall()  # fmt: skip
        except sqlite3.Error as e:
            raise StoreError(f"{self.path}: cannot read the incidents: {e}") from None
        finally:
            db.close()
        asked: dict[tuple[str, int], list[dict]] = {}
        for s, i, by, at in pending:
            asked.setdefault((s, i), []).append({"by": by, "asked_at": at})
        out = [{**json.loads(rec), "site": s, "seq": seq, "source": "site",
                "ack_pending": asked.get((s, json.loads(rec).get("id")), [])}
               for s, seq, rec in rows]  # fmt: skip
        return out + [_room_incident(r) for r in room]

    def open_counts(self) -> dict[str, dict[str, int]]:
        """Per site, its open incidents (not closed) by priority ("1".."4"), the control
        room's own with them."""
        db = self._reader()
        try:
            rows = db.execute("SELECT site, priority, COUNT(*) FROM incidents WHERE state IN "
                              "('active', 'acknowledged', 'cleared') GROUP BY site, priority "
                              "UNION ALL SELECT site, priority, COUNT(*) FROM room_incidents "
                              "WHERE state IN ('active', 'acknowledged', 'cleared') GROUP BY "
                              "site, priority").fetchall()  # fmt: skip
        except sqlite3.Error as e:
            raise StoreError(f"{self.path}: cannot read the incidents: {e}") from None
        finally:
            db.close()
        out: dict[str, dict[str, int]] = {}
        for site, priority, n in rows:
            by = out.setdefault(site, {})
            by[str(priority)] = by.get(str(priority), 0) + n
        return out

    def incident(self, site: str, incident: int) -> dict | None:
        """A site's incident as stored, None when the control room has none by that id."""
        db = self._reader()
        try:
            row = db.execute("SELECT record FROM incidents WHERE site = ? AND id = ?",
                             (site, incident)).fetchone()  # fmt: skip
        except sqlite3.Error as e:
            raise StoreError(f"{self.path}: cannot read the incidents: {e}") from None
        finally:
            db.close()
        return None if row is None else {**json.loads(row[0]), "site": site}

    def close(self) -> None:
        with self._lock:
            self.db.close()


_ROOM_COLUMNS = "id, site, kind, priority, state, raised_at, cleared_at, acked_by, acked_at, detail"


def _room_incident(row: tuple) -> dict:
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
