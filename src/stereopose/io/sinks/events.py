"""Where zone events go: JSON lines, SQLite, an HTTP webhook, a callback (the terminal).

Each is a sink of the frame loop (``write(frame)`` takes the frame's events, ``close()``); a
frame's events can also be given directly with ``write_events(events)``. The records come from
io.records.

- JSON lines: the events contract, one line per event, flushed at once.
- SQLite (the embedded log): WAL journal; each frame's events are one transaction, committed
  before `write` returns, so a process killed at any moment (even with SIGKILL) loses no
  committed event and leaves a readable database. An existing log is appended to; every run
  gets a row in `runs`.
- Webhook: POSTs each event as JSON from a background thread; retries with exponential backoff;
  a bounded queue that never blocks the frame loop (when it is full, the event is dropped and
  counted); `close` waits a bounded time for the queue to drain.
"""

from __future__ import annotations

import json
import logging
import queue
import sqlite3
import threading
import time
import urllib.error
import urllib.request
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import IO

from stereopose.errors import StereoposeError
from stereopose.io.records import EVENT_COLUMNS, event_from_record, event_record, event_row
from stereopose.io.sinks.base import ClosesOnce, FrameResult
from stereopose.io.writing import open_output
from stereopose.types import Event

logger = logging.getLogger(__name__)

COLUMNS = EVENT_COLUMNS

SCHEMA = """
CREATE TABLE IF NOT EXISTS runs (
    id INTEGER PRIMARY KEY,
    started REAL NOT NULL,           -- unix time
    site TEXT,
    source TEXT
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
    lost INTEGER NOT NULL DEFAULT 0
);
CREATE INDEX IF NOT EXISTS events_person ON events(person);
CREATE INDEX IF NOT EXISTS events_zone ON events(zone);
CREATE INDEX IF NOT EXISTS events_t ON events(t);
"""


class _EventSink(ClosesOnce):
    """The sink side shared by the event outputs: a frame's events to `write_events`."""

    stage = "write"

    def write(self, frame: FrameResult) -> None:
        self.write_events(frame.events)

    def write_events(self, events: Sequence[Event]) -> None:
        raise NotImplementedError

    def _close(self) -> list[Path]:
        return []


class JsonlSink(_EventSink):
    """Events as JSON lines (the contract), flushed as they come."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self._f: IO[str] = open_output(self.path, "events")

    def write_events(self, events: Sequence[Event]) -> None:
        if events:
            self._f.write("".join(json.dumps(event_record(e)) + "\n" for e in events))
            self._f.flush()

    def _close(self) -> list[Path]:
        self._f.close()
        return [self.path]


def read_events(path: str | Path) -> list[Event]:
    """Events back from a JSON lines file."""
    path = Path(path)
    out = []
    try:
        lines = path.read_text(encoding="utf-8").splitlines()
    except OSError as e:
        raise StereoposeError(f"{path}: cannot read events: {e.strerror}") from None
    for n, line in enumerate(lines, 1):
        if not line.strip():
            continue
        try:
            out.append(event_from_record(json.loads(line)))
        except (ValueError, KeyError, TypeError, IndexError) as e:
            raise StereoposeError(f"{path}:{n}: malformed event line: {e}") from None
    return out


class SqliteSink(_EventSink):
    """Events in an SQLite database (WAL), one transaction per frame with events."""

    def __init__(self, path: str | Path, site: str | None = None, source: str | None = None):
        self.path = Path(path)
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self.db = sqlite3.connect(self.path, isolation_level=None)
            self.db.execute("PRAGMA journal_mode=WAL")
            self.db.execute("PRAGMA synchronous=NORMAL")
            self.db.executescript(SCHEMA)
            cur = self.db.execute(
                "INSERT INTO runs(started, site, source) VALUES (?, ?, ?)",
                (time.time(), site, source),
            )
            self.run = int(cur.lastrowid)
        except sqlite3.DatabaseError as e:
            raise StereoposeError(f"{self.path}: cannot open the event database: {e}") from None
        self.committed = 0

    def write_events(self, events: Sequence[Event]) -> None:
        if not events:
            return
        rows = [event_row(e, self.run) for e in events]
        placeholders = ", ".join("?" * len(COLUMNS))
        try:
            self.db.execute("BEGIN")
            self.db.executemany(
                f"INSERT INTO events({', '.join(COLUMNS)}) VALUES ({placeholders})", rows
            )
            self.db.execute("COMMIT")
        except sqlite3.DatabaseError as e:
            raise StereoposeError(f"{self.path}: cannot store events: {e}") from None
        self.committed += len(rows)

    def _close(self) -> list[Path]:
        self.db.close()
        return [self.path]


def query_events(
    path: str | Path,
    person: int | None = None,
    zone: str | None = None,
    event_type: str | None = None,
    since: float | None = None,
) -> list[dict]:
    """Events of an SQLite log (every run), oldest first, filtered; rows as dicts of COLUMNS
    (``event_from_record`` turns one into an Event)."""
    path = Path(path)
    if not path.is_file():
        raise StereoposeError(f"{path}: event database not found")
    where, args = [], []
    for col, value in (("person", person), ("zone", zone), ("type", event_type)):
        if value is not None:
            where.append(f"{col} = ?")
            args.append(value)
    if since is not None:
        where.append("t >= ?")
        args.append(since)
    sql = f"SELECT {', '.join(COLUMNS)} FROM events"
    if where:
        sql += " WHERE " + " AND ".join(where)
    sql += " ORDER BY run, t, id"
    try:
        db = sqlite3.connect(f"file:{path}?mode=ro", uri=True)
        try:
            rows = db.execute(sql, args).fetchall()
        finally:
            db.close()
    except sqlite3.DatabaseError as e:
        raise StereoposeError(f"{path}: not a readable event database: {e}") from None
    return [dict(zip(COLUMNS, r, strict=True)) for r in rows]


class WebhookSink(_EventSink):
    """POSTs events as JSON to a URL from a background thread, never blocking `write`.

    queue_size: events waiting at most; more are dropped (counted in `dropped`). An event whose
    POST fails is retried `retries` times, waiting backoff_s, 2 backoff_s, ... (capped at
    max_backoff_s); then it is dropped (counted in `failed`). `close` waits up to
    drain_timeout_s for the queue to empty.
    """

    def __init__(
        self,
        url: str,
        queue_size: int = 1000,
        retries: int = 4,
        backoff_s: float = 0.5,
        max_backoff_s: float = 8.0,
        timeout_s: float = 5.0,
        drain_timeout_s: float = 10.0,
        sleep: Callable[[float], None] | None = None,
    ) -> None:
        if not url.startswith(("http://", "https://")):
            raise StereoposeError(f"webhook URL must start with http:// or https://, got {url!r}")
        self.url = url
        self.retries, self.backoff_s, self.max_backoff_s = retries, backoff_s, max_backoff_s
        self.timeout_s, self.drain_timeout_s = timeout_s, drain_timeout_s
        self.queue: queue.Queue[Event | None] = queue.Queue(maxsize=queue_size)
        self.sent = self.dropped = self.failed = self.retried = 0
        self._stop = threading.Event()
        self._sleep = sleep or self._stop.wait
        self._thread = threading.Thread(target=self._run, name="webhook", daemon=True)
        self._thread.start()

    def write_events(self, events: Iterable[Event]) -> None:
        for e in events:
            try:
                self.queue.put_nowait(e)
            except queue.Full:
                self.dropped += 1

    def _post(self, event: Event) -> None:
        body = json.dumps(event_record(event)).encode()
        req = urllib.request.Request(
            self.url, data=body, headers={"Content-Type": "application/json"}, method="POST"
        )
        with urllib.request.urlopen(req, timeout=self.timeout_s) as resp:
            resp.read()

    def _deliver(self, event: Event) -> None:
        delay = self.backoff_s
        for attempt in range(self.retries + 1):
            try:
                self._post(event)
                self.sent += 1
                return
            except (urllib.error.URLError, OSError, ValueError) as e:
                if attempt == self.retries or self._stop.is_set():
                    self.failed += 1
                    logger.warning(
                        "webhook %s: event dropped after %d tries: %s", self.url, attempt + 1, e
                    )
                    return
                self.retried += 1
                self._sleep(delay)
                delay = min(2 * delay, self.max_backoff_s)

    def _run(self) -> None:
        while True:
            event = self.queue.get()
            if event is None:
                return
            self._deliver(event)

    def _close(self) -> list[Path]:
        deadline = time.monotonic() + self.drain_timeout_s
        while not self.queue.empty() and time.monotonic() < deadline:
            time.sleep(0.02)
        self._stop.set()  # retries stop waiting; what is still queued is dropped
        while True:
            try:
                if self.queue.get_nowait() is not None:
                    self.dropped += 1
            except queue.Empty:
                break
        self.queue.put(None)
        self._thread.join(timeout=self.timeout_s + 1.0)
        if self.dropped or self.failed:
            logger.warning(
                "webhook %s: %d event(s) sent, %d dropped (queue full or closing), %d failed",
                self.url,
                self.sent,
                self.dropped,
                self.failed,
            )
        return []


class CallbackSink(_EventSink):
    """Hands each frame's events (when there are any) to a callable."""

    def __init__(self, call: Callable[[list[Event]], None]) -> None:
        self.call = call

    def write_events(self, events: Sequence[Event]) -> None:
        if events:
            self.call(list(events))


def describe(e: Event) -> str:
    """One line for the terminal."""
    extra = []
    if e.joint:
        extra.append(e.joint)
    if e.distance_m is not None:
        extra.append(f"{e.distance_m:.2f} m away")
    if e.duration_s is not None:
        extra.append(f"after {e.duration_s:.1f} s")
    if e.allowed:
        extra.append("allowed")
    if e.lost:
        extra.append("track lost")
    more = f" ({', '.join(extra)})" if extra else ""
    return (
        f"t={e.t:8.2f}s frame {e.frame:6d}  person {e.person:3d}  {e.type:14s} "
        f"{e.zone} [{e.kind}]{more}"
    )
