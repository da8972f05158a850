"""Acknowledgements of events: who acknowledged which event and when, in the event log.

The `acks` table lives in `events.sqlite` beside the events it names, through a connection of
its own (WAL, a short busy timeout, so the frame loop's writes and an acknowledgement never
hold each other up for long). An event is acknowledged once: the first acknowledgement stays,
a second one answers with it. An acknowledgement belongs to one event for ever: event ids
are never given again (io.sinks.eventdb's high-water marks), retention deletes an event's
acknowledgement in the transaction that deletes the event (site.storage), and any left
by an earlier version are deleted as the log is opened.
"""

from __future__ import annotations

import sqlite3
import threading
import time
from collections.abc import Iterable
from pathlib import Path

from stereopose.errors import StereoposeError
from stereopose.io.sinks.eventdb import connect_writer, create_schema, raise_marks

BUSY_MS = 500


class AckError(StereoposeError):
    """The acknowledgement could not be stored (the log is locked or unreadable)."""


class AckStore:
    """Acknowledgements in the event log at `path` (created with the log's first writer)."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self._lock = threading.Lock()
        self._db: sqlite3.Connection | None = None

    def _conn(self) -> sqlite3.Connection | None:
        """The connection, opened once the log exists (None before)."""
        if self._db is not None:
            return self._db
        if not self.path.is_file():
            return None
        db = None
        try:
            # the writer's settings; the marks raised (above every id an ack names) before
            # the acks of events gone are deleted
            db = connect_writer(self.path, BUSY_MS / 1000)
            create_schema(db)
            raise_marks(db)
            db.execute("DELETE FROM acks WHERE event NOT IN (SELECT id FROM events)")
        except sqlite3.Error as e:
            if db is not None:
                db.close()
            raise AckError(f"{self.path}: cannot open the acknowledgements: {e}") from None
        self._db = db
        return db

    def ack(self, event: int, by: str) -> tuple[dict, bool] | None:
        """Acknowledge `event` as `by`: ({"by", "at"}, whether this call made it); None when
        the log has no such event."""
        with self._lock:
            db = self._conn()
            if db is None:
                return None
            try:
                db.execute("BEGIN IMMEDIATE")
                try:
                    if db.execute("SELECT 1 FROM events WHERE id = ?", (event,)).fetchone() is None:
                        db.execute("ROLLBACK")
                        return None
                    cur = db.execute(
                        "INSERT OR IGNORE INTO acks(event, by, at) VALUES (?, ?, ?)",
                        (event, by, time.time()),
                    )
                    made = cur.rowcount == 1
                    row = db.execute("SELECT by, at FROM acks WHERE event = ?", (event,)).fetchone()
                    db.execute("COMMIT")
                except BaseException:
                    if db.in_transaction:
                        db.execute("ROLLBACK")
                    raise
            except sqlite3.Error as e:
                raise AckError(f"{self.path}: cannot store the acknowledgement: {e}") from None
        return {"by": row[0], "at": row[1]}, made

    def of(self, events: Iterable[int]) -> dict[int, dict]:
        """event id -> {"by", "at"} for those acknowledged."""
        ids = list(events)
        if not ids:
            return {}
        with self._lock:
            db = self._conn()
            if db is None:
                return {}
            out: dict[int, dict] = {}
            try:
                for i in range(0, len(ids), 500):
                    chunk = ids[i : i + 500]
                    marks = ", ".join("?" * len(chunk))
                    for event, by, at in db.execute(
                        f"SELECT event, by, at FROM acks WHERE event IN ({marks})", chunk
                    ):
                        out[event] = {"by": by, "at": at}
            except sqlite3.Error as e:
                raise AckError(f"{self.path}: cannot read the acknowledgements: {e}") from None
        return out

    def close(self) -> None:
        with self._lock:
            if self._db is not None:
                self._db.close()
                self._db = None
