"""The control room's store: its sites and every site's events, each (site, id) once, their
incidents, the acknowledgements asked of them and the control room's own incidents.

SQLite by default (WAL, one writer: the ingest's thread; readers open their own read-only
connections) in the control room's output folder (`control.sqlite`), or PostgreSQL for a
fleet (`[control_room] database = "postgresql://..."`, psycopg 3: one writing connection,
one reading connection, each reconnected when the server was away): the tables and
statements of controlroom.schema serve both. The events table's primary key is (site, id):
an event sent twice (a QoS 1 resend, a replay, a bridge's duplicates) is stored once, and
the duplicate counted. A site's mark (the highest id stored with nothing missing before it,
site.outbox's protocol) is kept with the site, in the same transaction as the events that
raise it, so a control room killed at any moment restarts with a mark that only names what
it holds.
"""

from __future__ import annotations

import contextlib
import json
import re
import sqlite3
import threading
from collections.abc import Iterable, Iterator, Sequence
from pathlib import Path
from urllib.request import pathname2url

from stereopose.controlroom.schema import (
    ADDED,
    PUT_CHANGE,
    PUT_EVENT,
    RAISE_INCIDENT_MARK,
    RAISE_MARK,
    ROOM_COLUMNS,
    SCHEMA_LOCK,
    Dialect,
    Run,
    SiteRow,
    change_row,
    event_row,
    of_sites,
    room_record,
)
from stereopose.errors import StereoposeError
from stereopose.io.dbapi import Connection, as_connection

__all__ = ["ControlStore", "SiteRow", "StoreError", "shown_database"]

OPEN_STATES = ("active", "acknowledged", "cleared")
MAX_LIMIT = 1000


class StoreError(StereoposeError):
    """The control room's store cannot be opened, read or written."""


class ControlStore:
    """The store at `database`: a postgresql:// (or postgres://) URL, else an SQLite file's
    path (the tables made when missing). Writes come
    from one thread (the ingest's; an acknowledgement asked from the API's), under a lock;
    reads from any thread."""

    def __init__(self, database: str | Path) -> None:
        text = str(database)
        self.postgres = text.startswith(("postgresql://", "postgres://"))
        self.dialect = Dialect(self.postgres)
        self.url = text if self.postgres else None
        self.path = Path(text) if not self.postgres else None
        self.name = shown_database(text) if self.postgres else str(self.path)
        self._lock = threading.Lock()
        self._read_lock = threading.Lock()
        self._errors: tuple[type[BaseException], ...] = (sqlite3.Error,)
        self._reader_db: Connection | None = None
        if self.postgres:
            try:
                import psycopg
            except ImportError:
                raise StoreError(
                    f"{self.name}: PostgreSQL needs psycopg 3 (pip install "
                    "'stereopose[postgresql]')"
                ) from None
            self._psycopg = psycopg
            self._errors = (psycopg.Error, OSError)
        self.db: Connection | None = None
        try:
            db = self._writer()
            if self.postgres:  # several workers starting at once make the tables one at a time
                db.execute("SELECT pg_advisory_xact_lock(%s)", (SCHEMA_LOCK,))
            for st in self.dialect.schema():
                db.execute(st)
            for table, column, decl in ADDED:
                if column not in self._columns(db, table):
                    db.execute(f"ALTER TABLE {table} ADD COLUMN {column} {decl}")
            db.commit()
        except (*self._errors, OSError) as e:
            self._close_writer()
            raise StoreError(
                f"{self.name}: cannot open the control room's store: {_why(e)}"
            ) from None
        self.duplicates = 0
        self.stored = 0

    # --- connections -----------------------------------------------------------------------

    def _connect(self, read_only: bool = False) -> Connection:
        if self.url is not None:
            pg = self._psycopg.connect(self.url, connect_timeout=5, autocommit=read_only)
            if read_only:
                pg.read_only = True
            return as_connection(pg)
        assert self.path is not None  # SQLite's file, where not PostgreSQL
        if read_only:
            db = sqlite3.connect(
                f"file:{pathname2url(str(self.path.resolve()))}?mode=ro", uri=True, timeout=2.0
            )
            db.execute("PRAGMA busy_timeout = 2000")
            return as_connection(db)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        db = sqlite3.connect(self.path, timeout=5.0, check_same_thread=False)
        db.execute("PRAGMA journal_mode = WAL")
        db.execute("PRAGMA synchronous = NORMAL")
        return as_connection(db)

    def _lost(self, db: Connection | None) -> bool:
        """A PostgreSQL connection closed or broken (its server gone); never a SQLite one."""
        if not self.postgres or db is None:
            return False
        pg = self._psycopg.Connection
        return isinstance(db, pg) and bool(db.closed or db.broken)

    def _writer(self) -> Connection:
        """The writing connection (made again when a PostgreSQL server dropped it)."""
        if self._lost(self.db):
            self._close_writer()
        if self.db is None:
            self.db = self._connect()
        return self.db

    def _close_writer(self) -> None:
        if self.db is not None:
            with contextlib.suppress(Exception):
                self.db.close()
        self.db = None

    def _columns(self, db: Connection, table: str) -> set[str]:
        if self.postgres:
            rows = db.execute(
                "SELECT column_name FROM information_schema.columns WHERE table_name = %s", (table,)
            ).fetchall()
            return {r[0] for r in rows}
        return {r[1] for r in db.execute(f"PRAGMA table_info({table})")}

    @contextlib.contextmanager
    def writing(self, what: str) -> Iterator:
        """The writer in one transaction under the lock: committed at the end, rolled back
        (and a StoreError naming `what`) on an error."""
        with self._lock:
            try:
                db = self._writer()
                yield Run(db, self.dialect)
                db.commit()
            except self._errors as e:
                if self.db is not None:
                    with contextlib.suppress(Exception):
                        self.db.rollback()
                    if self._lost(self.db):
                        self._close_writer()
                raise StoreError(f"{self.name}: cannot {what}: {_why(e)}") from None

    @contextlib.contextmanager
    def reading(self, what: str) -> Iterator:
        """A reading connection: SQLite's read-only one per call; PostgreSQL's one shared."""
        try:
            if not self.postgres:
                db = self._connect(read_only=True)
                try:
                    yield Run(db, self.dialect)
                finally:
                    db.close()
                return
            with self._read_lock:
                if self._reader_db is None or self._lost(self._reader_db):
                    self._reader_db = self._connect(read_only=True)
                yield Run(self._reader_db, self.dialect)
        except self._errors as e:
            raise StoreError(f"{self.name}: cannot {what}: {_why(e)}") from None

    # --- writes ----------------------------------------------------------------------------

    def put_events(self, site: str, events: Sequence[dict], mark: int, now: float) -> int:
        """Store a site's events (each (site, id) once) and its new mark, in one transaction;
        the number newly stored."""
        rows = [event_row(site, e, now) for e in events]
        with self.writing(f"store {len(rows)} event(s) of site {site!r}") as run:
            new = run.many(PUT_EVENT, rows)
            run(RAISE_MARK, (site, mark, now))
        self.stored += new
        self.duplicates += len(rows) - new
        return new

    def put_batch(
        self,
        events: dict[str, tuple[Sequence[dict], int]],
        changes: dict[str, tuple[Sequence[dict], int]],
        now: float,
    ) -> tuple[int, int]:
        """Many sites' events and incident changes with their new marks ({site: (items,
        mark)}), in one transaction (one commit however many sites: what a fleet's store
        needs); (events newly stored, incident records written)."""
        ev_rows = [event_row(site, e, now) for site, (items, _) in events.items() for e in items]
        ch_rows = [change_row(site, c, now) for site, (items, _) in changes.items() for c in items]
        what = f"store {len(ev_rows)} event(s) and {len(ch_rows)} incident change(s)"
        with self.writing(what) as run:
            new = run.many(PUT_EVENT, ev_rows)
            written = run.many(PUT_CHANGE, ch_rows)
            run.many(RAISE_MARK, [(site, mark, now) for site, (_, mark) in events.items()])
            run.many(
                RAISE_INCIDENT_MARK, [(site, mark, now) for site, (_, mark) in changes.items()]
            )
        self.stored += new
        self.duplicates += len(ev_rows) - new
        return new, written

    def put_incidents(self, site: str, changes: Sequence[dict], mark: int, now: float) -> int:
        """Store a site's incident changes ({"seq", "incident": record}; a record replaces the
        stored one only when its seq is newer) and its new incidents mark, in one
        transaction; the number of records written."""
        rows = [change_row(site, c, now) for c in changes]
        with self.writing(f"store {len(rows)} incident change(s) of site {site!r}") as run:
            new = run.many(PUT_CHANGE, rows)
            run(RAISE_INCIDENT_MARK, (site, mark, now))
        return new

    def add_command(self, site: str, incident: int, by: str, now: float) -> int:
        """An acknowledgement to ask of `site`; its command id."""
        with self.writing("store the acknowledgement") as run:
            row = run(
                "INSERT INTO commands(site, incident, asked_by, asked_at) VALUES "
                "(?, ?, ?, ?) RETURNING id",
                (site, incident, by, now),
            )
            row = row.fetchone()
        return int(row[0])

    def finish_command(
        self, command: int, result: str, now: float, site: str | None = None
    ) -> bool:
        """The site's answer to `command` (of `site` when given); whether it was waiting."""
        sql = "UPDATE commands SET done_at = ?, result = ? WHERE id = ? AND done_at IS NULL"
        args: list = [now, result, command]
        if site is not None:
            sql += " AND site = ?"
            args.append(site)
        with self.writing("store a site's answer") as run:
            cur = run(sql, args)
        return cur.rowcount > 0

    def pending_commands(self) -> list[tuple[int, str, int, str]]:
        """(command, site, incident, by) not answered yet, oldest first."""
        with self.writing("read the acknowledgements") as run:
            rows = run(
                "SELECT id, site, incident, asked_by FROM commands WHERE done_at IS "
                "NULL ORDER BY id"
            ).fetchall()
        return [tuple(r) for r in rows]

    def raise_room_incident(
        self, site: str, kind: str, priority: int, detail: str, now: float
    ) -> int | None:
        """A control-room incident of `kind` about `site`, unless one is active already; its
        id (None: one was)."""
        with self.writing("raise an incident") as run:
            if run(
                "SELECT 1 FROM room_incidents WHERE site = ? AND kind = ? AND state IN "
                "('active', 'acknowledged')",
                (site, kind),
            ).fetchone():
                return None
            row = run(
                "INSERT INTO room_incidents(site, kind, priority, state, raised_at, "
                "detail) VALUES (?, ?, ?, 'active', ?, ?) RETURNING id",
                (site, kind, priority, now, detail),
            ).fetchone()
        return int(row[0])

    def clear_room_incidents(self, site: str, kind: str, now: float) -> int:
        """The active incidents of `kind` about `site` cleared (closed when acknowledged)."""
        with self.writing("clear an incident") as run:
            cur = run(
                "UPDATE room_incidents SET cleared_at = ?, state = CASE state WHEN "
                "'acknowledged' THEN 'closed' ELSE 'cleared' END WHERE site = ? AND "
                "kind = ? AND state IN ('active', 'acknowledged')",
                (now, site, kind),
            )
        return cur.rowcount

    def ack_room_incident(self, incident: int, by: str, now: float) -> dict | None:
        """Acknowledge a control-room incident (a cleared one closes); its row, None when
        there is none with that id."""
        with self.writing("acknowledge an incident") as run:
            run(
                "UPDATE room_incidents SET acked_by = ?, acked_at = ?, state = CASE state "
                "WHEN 'active' THEN 'acknowledged' WHEN 'cleared' THEN 'closed' ELSE state "
                "END WHERE id = ? AND acked_by IS NULL",
                (by, now, incident),
            )
            row = run(
                f"SELECT {ROOM_COLUMNS} FROM room_incidents WHERE id = ?", (incident,)
            ).fetchone()
        return None if row is None else room_record(row)

    def prune(self, before: float) -> int:
        """The events stored before `before` (Unix time), and the closed incidents, answered
        commands and closed control-room incidents last changed before it, deleted; the rows
        deleted. The sites and their marks stay, so nothing pruned is stored again."""
        n = 0
        with self.writing("prune the store") as run:
            for sql in (
                "DELETE FROM events WHERE stored_at < ?",
                "DELETE FROM incidents WHERE state = 'closed' AND stored_at < ?",
                "DELETE FROM commands WHERE done_at IS NOT NULL AND done_at < ?",
                "DELETE FROM room_incidents WHERE state = 'closed' AND "
                "COALESCE(cleared_at, raised_at) < ?",
            ):
                n += max(0, run(sql, (before,)).rowcount)
        return n

    def set_site(
        self,
        site: str,
        *,
        state: str | None = None,
        last_seen: float | None = None,
        health: dict | None = None,
    ) -> None:
        with self.writing(f"update site {site!r}") as run:
            run("INSERT OR IGNORE INTO sites(site) VALUES (?)", (site,))
            if state is not None:
                run("UPDATE sites SET state = ? WHERE site = ?", (state, site))
            if last_seen is not None:
                run(
                    "UPDATE sites SET last_seen = GREATEST(COALESCE(last_seen, 0), ?) WHERE "
                    "site = ?",
                    (last_seen, site),
                )
            if health is not None:
                run("UPDATE sites SET health = ? WHERE site = ?", (json.dumps(health), site))

    def set_summaries(self, summaries: dict[str, dict]) -> None:
        """Each site's latest summary (its heartbeat's status, cameras, people), at once."""
        with self.writing("update the sites") as run:
            run.many(
                "INSERT INTO sites(site, health) VALUES (?, ?) ON CONFLICT(site) DO "
                "UPDATE SET health = excluded.health",
                [(site, json.dumps(v)) for site, v in summaries.items()],
            )

    def marks(self) -> dict[str, int]:
        with self.writing("read the marks") as run:
            return {s: int(m) for s, m in run("SELECT site, mark FROM sites").fetchall()}

    def incident_marks(self) -> dict[str, int]:
        with self.writing("read the marks") as run:
            return {s: int(m) for s, m in run("SELECT site, incident_mark FROM sites").fetchall()}

    # --- reads -----------------------------------------------------------------------------

    def sites(self, only: Iterable[str] | None = None) -> list[SiteRow]:
        with self.reading("read the sites") as run:
            rows = run(
                "SELECT s.site, s.mark, s.state, s.last_seen, s.health, "
                "(SELECT COUNT(*) FROM events e WHERE e.site = s.site) "
                "FROM sites s ORDER BY s.site"
            ).fetchall()
        keep = None if only is None else set(only)
        return [
            SiteRow(s, int(m), st, seen, json.loads(h) if h else None, int(n))
            for s, m, st, seen, h, n in rows
            if keep is None or s in keep
        ]

    def events(
        self,
        site: str | None = None,
        after_id: int = 0,
        limit: int = 100,
        sites: Iterable[str] | None = None,
    ) -> list[dict]:
        """Events in (site, id) order: of `site` after `after_id`, or of every site (of
        `sites` when given); at most `limit` (<= MAX_LIMIT)."""
        limit = max(1, min(int(limit), MAX_LIMIT))
        where, args = of_sites(site, sites)
        where.append("id > ?")
        args.append(int(after_id))
        with self.reading("read the events") as run:
            rows = run(
                f"SELECT site, record FROM events WHERE {' AND '.join(where)} "
                "ORDER BY site, id LIMIT ?",
                [*args, limit],
            ).fetchall()
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
        where, args = of_sites(site, sites)
        if state == "open":
            where.append("state IN ('active', 'acknowledged', 'cleared')")
        elif state is not None:
            where.append("state = ?")
            args.append(state)
        cond = f" WHERE {' AND '.join(where)}" if where else ""
        with self.reading("read the incidents") as run:
            rows = run(
                f"SELECT site, seq, record FROM incidents{cond} ORDER BY stored_at "
                "DESC, site, id DESC LIMIT ?",
                [*args, limit],
            ).fetchall()
            room = run(
                f"SELECT {ROOM_COLUMNS} FROM room_incidents{cond} ORDER BY id DESC LIMIT ?",
                [*args, limit],
            ).fetchall()
            pending = run(
                "SELECT site, incident, asked_by, asked_at FROM commands WHERE done_at IS NULL"
            ).fetchall()
        asked: dict[tuple[str, int], list[dict]] = {}
        for s, i, by, at in pending:
            asked.setdefault((s, int(i)), []).append({"by": by, "asked_at": at})
        out = []
        for s, seq, rec in rows:
            doc = json.loads(rec)
            out.append(
                {
                    **doc,
                    "site": s,
                    "seq": int(seq),
                    "source": "site",
                    "ack_pending": asked.get((s, doc.get("id")), []),
                }
            )
        return out + [room_record(r) for r in room]

    def open_counts(self) -> dict[str, dict[str, int]]:
        """Per site, its open incidents (not closed) by priority ("1".."4"), the control
        room's own with them."""
        with self.reading("read the incidents") as run:
            rows = run(
                "SELECT site, priority, COUNT(*) FROM incidents WHERE state IN "
                "('active', 'acknowledged', 'cleared') GROUP BY site, priority "
                "UNION ALL SELECT site, priority, COUNT(*) FROM room_incidents "
                "WHERE state IN ('active', 'acknowledged', 'cleared') GROUP BY "
                "site, priority"
            ).fetchall()
        out: dict[str, dict[str, int]] = {}
        for site, priority, n in rows:
            by = out.setdefault(site, {})
            by[str(priority)] = by.get(str(priority), 0) + int(n)
        return out

    def room_incident(self, incident: int) -> dict | None:
        """A control-room incident, None when there is none with that id."""
        with self.reading("read the incidents") as run:
            row = run(
                f"SELECT {ROOM_COLUMNS} FROM room_incidents WHERE id = ?", (incident,)
            ).fetchone()
        return None if row is None else room_record(row)

    def incident(self, site: str, incident: int) -> dict | None:
        """A site's incident as stored, None when the control room has none by that id."""
        with self.reading("read the incidents") as run:
            row = run(
                "SELECT record FROM incidents WHERE site = ? AND id = ?", (site, incident)
            ).fetchone()
        return None if row is None else {**json.loads(row[0]), "site": site}

    def close(self) -> None:
        with self._lock:
            self._close_writer()
        with self._read_lock:
            if self._reader_db is not None:
                with contextlib.suppress(Exception):
                    self._reader_db.close()
                self._reader_db = None


def shown_database(database: str | Path) -> str:
    """A store's name as it may be shown: a URL without its password."""
    return re.sub(r"(://[^:/@]*):[^@]*@", r"\1:***@", str(database))


def _why(e: BaseException) -> str:
    return str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
