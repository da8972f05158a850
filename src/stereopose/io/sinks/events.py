"""Where zone events go: JSON lines, SQLite, an HTTP webhook, a callback (the terminal).

Each is a sink of the frame loop (``write(frame)`` takes the frame's events, ``close()``); a
frame's events can also be given directly with ``write_events(events)``. The records come from
io.records.

- JSON lines: the events contract, one line per event, flushed at once.
- SQLite (the embedded log): WAL journal; each frame's events are one transaction, committed
  before `write` returns, so a process killed at any moment (even with SIGKILL) loses no
  committed event and leaves a readable database. Event ids come from the log's high-water
  mark (io.sinks.eventdb), taken in the transaction that stores them: they strictly increase
  for the life of the log, whatever retention deleted, so (site, id) names one event for
  ever. An existing log is appended to; every run gets a row in `runs`. A log locked by
  another process does not hold up the frame loop: its events wait in memory and are stored
  with a later frame's (see SqliteSink).
- Webhook (io.sinks.webhook): POSTs each event as JSON from a background thread that no reply
  can stop; retries with a bounded backoff; a bounded queue that never blocks the frame loop;
  every event counted once, delivered, failed or dropped.
"""

from __future__ import annotations

import json
import logging
import sqlite3
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import IO
from urllib.request import pathname2url

from stereopose.errors import StereoposeError
from stereopose.io.records import EVENT_COLUMNS, event_from_record, event_record
from stereopose.io.sinks.base import ClosesOnce, FrameResult
from stereopose.io.sinks.eventdb import (
    reading,
    table_columns,
)
from stereopose.io.sinks.webhook import WebhookSink
from stereopose.io.writing import open_output
from stereopose.types import Event

__all__ = [
    "COLUMNS",
    "CallbackSink",
    "JsonlSink",
    "WebhookSink",
    "describe",
    "query_events",
    "read_events",
]

logger = logging.getLogger(__name__)

COLUMNS = EVENT_COLUMNS


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
    except UnicodeDecodeError as e:
        raise StereoposeError(f"{path}: cannot read events: not UTF-8 text ({e.reason})") from None
    for n, line in enumerate(lines, 1):
        if not line.strip():
            continue
        try:
            out.append(event_from_record(json.loads(line)))
        except (ValueError, KeyError, TypeError, IndexError, OverflowError) as e:
            raise StereoposeError(f"{path}:{n}: malformed event line: {e}") from None
        except RecursionError:
            raise StereoposeError(f"{path}:{n}: malformed event line: nested too deeply") from None
    return out


def _is_text(value: str) -> bool:
    """Whether SQLite can take value (a command line can carry undecodable bytes)."""
    try:
        value.encode("utf-8")
    except UnicodeEncodeError:
        return False
    return True


def query_events(
    path: str | Path,
    person: int | None = None,
    zone: str | None = None,
    event_type: str | None = None,
    since: float | None = None,
) -> list[dict]:
    """Events of an SQLite log (every run), oldest first, filtered; rows as dicts of COLUMNS
    (``event_from_record`` turns one into an Event). A person id beyond SQLite's 64-bit
    integers matches no event; a zone or type that is not valid text is a StereoposeError."""
    path = Path(path)
    if not path.is_file():
        raise StereoposeError(f"{path}: event database not found")
    if person is not None and not -(2**63) <= person < 2**63:
        return []  # no stored id is that large
    for what, text in (("zone", zone), ("type", event_type)):
        if text is not None and not _is_text(text):
            raise StereoposeError(f"{path}: the {what} to look for, {text!r}, is not valid text")
    where, args = [], []
    for col, value in (("person", person), ("zone", zone), ("type", event_type)):
        if value is not None:
            where.append(f"{col} = ?")
            args.append(value)
    if since is not None:
        where.append("t >= ?")
        args.append(since)
    sql = "SELECT {} FROM events"
    if where:
        sql += " WHERE " + " AND ".join(where)
    sql += " ORDER BY run, t, id"

    def read() -> list:
        db = sqlite3.connect(f"file:{pathname2url(str(path.resolve()))}?mode=ro", uri=True)
        try:
            return db.execute(sql.format(_select(db)), args).fetchall()
        finally:
            db.close()

    try:
        rows = reading(read)
    except sqlite3.DatabaseError as e:
        raise StereoposeError(f"{path}: not a readable event database: {e}") from None
    return [dict(zip(COLUMNS, r, strict=True)) for r in rows]


def _select(db: sqlite3.Connection) -> str:
    """COLUMNS as a select list; those a log of an earlier version lacks read as NULL (0 for
    restart), so old logs stay readable without being changed."""
    have = table_columns(db, "events")
    if not have:
        raise sqlite3.DatabaseError("no events table")
    return ", ".join(c if c in have else ("0" if c == "restart" else "NULL") for c in COLUMNS)


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
    if e.rule is not None:  # a behaviour event: what explains it
        extra += [x for x in (e.posture, e.failed and f"failed: {e.failed}") if x]
        if e.nearest_m is not None:
            extra.append(f"nearest {e.nearest_m:.1f} m")
        if e.height_m is not None:
            extra.append(f"at {e.height_m:.2f} m")
    if e.ticket is not None:  # a ticket's event: which ticket, which step, what went wrong
        if e.rule is None and e.failed:
            extra.append(f"failed: {e.failed}")
        if e.result is not None and "done" in e.result:
            extra.append(
                f"{len(e.result['done'])}/{e.result.get('steps', '?')} steps done, "
                f"{e.result.get('deviations', 0)} deviations"
            )
    more = f" ({', '.join(extra)})" if extra else ""
    where = f"{e.rule}{' ' + e.zone if e.zone else ''}" if e.rule is not None else e.zone
    if e.ticket is not None:
        where = (
            f"{e.ticket}{': ' + repr(e.step) if e.step else ''}{' at ' + e.zone if e.zone else ''}"
        )
    return (
        f"t={e.t:8.2f}s frame {e.frame:6d}  person {e.person:3d}  {e.type:14s} "
        f"{where} [{e.kind}]{more}"
    )
