"""Events the event log could not store yet, kept in a file beside it until it can.

While SqliteSink cannot commit (the log locked by another process, a full disk), its events
wait in memory, and the other sinks (MQTT, the webhook, the console) have already sent them:
a process killed then would lose the only record of an enter that the far side saw, and the
next start could not close that zone. So the waiting events are appended, as they start to
wait, to `<log>.pending.jsonl` (one JSON object a line: `{"run": N, "event": {...}}`, the
event as the events contract writes it); the file is emptied once they are stored. The next
start reads it as part of the log (site.restart: the zones and alarms it leaves open), and
the next SqliteSink stores its events in the log, each once, then removes the file.

Incident records waiting with them (alarms: a change of an incident the other outputs have
published) are kept in the same file, `{"run": N, "incident": {...}, "wall_start": W}` (the
record as the incidents table holds it; the latest line of an incident wins): the next start
takes back the incidents they leave open, and stores them in the log's incidents table.
"""

from __future__ import annotations

import json
import logging
import sqlite3
from collections.abc import Sequence
from pathlib import Path

from stereopose.alarms import IncidentRecord
from stereopose.alarms.incident import IncidentError
from stereopose.io.records import EVENT_COLUMNS, event_from_record, event_record, event_row
from stereopose.io.sinks.eventdb import take
from stereopose.io.sinks.incidents import upsert_incidents
from stereopose.types import Event

__all__ = ["Spill", "read_spill", "read_spilled_incidents", "spill_path", "store_spill"]

logger = logging.getLogger(__name__)

SUFFIX = ".pending.jsonl"
# what makes two events the same one: a person enters a zone (or an alarm starts) once a frame
_SAME = "run = ? AND frame = ? AND person = ? AND zone = ? AND type = ? AND ABS(t - ?) < 1e-5"


def spill_path(log: str | Path) -> Path:
    log = Path(log)
    return log.with_name(log.name + SUFFIX)


class Spill:
    """The file of the events waiting for the log at `log`; `error`: why the last append
    failed (None: it did not)."""

    def __init__(self, log: str | Path) -> None:
        self.path = spill_path(log)
        self.error: str | None = None
        self._written = False

    def add(self, run: int, events: Sequence[Event]) -> bool:
        """Appends events (flushed: a kill after it loses none); whether they are kept."""
        if not events:
            return True
        try:
            with self.path.open("a", encoding="utf-8") as f:
                f.write(
                    "".join(
                        json.dumps({"run": run, "event": event_record(e)}) + "\n" for e in events
                    )
                )
        except OSError as e:
            if self.error is None:
                logger.error(
                    "%s: cannot keep the events waiting for the log: %s", self.path, e.strerror
                )
            self.error = e.strerror or str(e)
            return False
        self._written, self.error = True, None
        return True

    def add_incidents(self, run: int, held: Sequence[tuple[IncidentRecord, float | None]]) -> bool:
        """Appends incident records, each (record, wall_start), flushed; whether they are kept."""
        if not held:
            return True
        try:
            with self.path.open("a", encoding="utf-8") as f:
                f.write(
                    "".join(
                        json.dumps({"run": run, "incident": rec.to_dict(), "wall_start": wall})
                        + "\n"
                        for rec, wall in held
                    )
                )
        except OSError as e:
            if self.error is None:
                logger.error(
                    "%s: cannot keep the incidents waiting for the log: %s", self.path, e.strerror
                )
            self.error = e.strerror or str(e)
            return False
        self._written, self.error = True, None
        return True

    def clear(self) -> None:
        """Every event of the file is stored: the file goes."""
        if self._written:
            try:
                self.path.unlink(missing_ok=True)
            except OSError as e:
                logger.warning("%s: cannot remove it: %s", self.path, e.strerror)
            self._written = False


def _lines(log: str | Path) -> tuple[Path, list[str]]:
    path = spill_path(log)
    try:
        return path, path.read_text(encoding="utf-8", errors="replace").splitlines()
    except FileNotFoundError:
        return path, []
    except OSError as e:
        logger.warning("%s: cannot read the events waiting for the log: %s", path, e.strerror)
        return path, []


def read_spill(log: str | Path) -> list[tuple[int, Event]]:
    """(run, event) of the file beside the log at `log`, in order ([] when there is none); a
    line that is not one (a write cut by a kill) is skipped with a warning, an incident's line
    (read_spilled_incidents) without one."""
    path, lines = _lines(log)
    out = []
    for n, line in enumerate(lines, 1):
        try:
            doc = json.loads(line)
            if isinstance(doc, dict) and "incident" in doc and "event" not in doc:
                continue
            out.append((int(doc["run"]), event_from_record(doc["event"])))
        except (ValueError, KeyError, TypeError, IndexError, OverflowError, RecursionError):
            if line.strip():
                logger.warning("%s:%d: not an event waiting for the log; skipped", path, n)
    return out


def read_spilled_incidents(log: str | Path) -> dict[int, tuple[IncidentRecord, float | None]]:
    """Incident id -> (record, wall_start) of the file beside the log, the latest line of each;
    a damaged incident line is skipped with a warning."""
    path, lines = _lines(log)
    out: dict[int, tuple[IncidentRecord, float | None]] = {}
    for n, line in enumerate(lines, 1):
        try:
            doc = json.loads(line)
            if not isinstance(doc, dict) or "incident" not in doc:
                continue
            rec = IncidentRecord.from_dict(doc["incident"])
            wall = doc.get("wall_start")
            out[int(rec.id)] = (rec, None if wall is None else float(wall))
        except (
            IncidentError,
            ValueError,
            KeyError,
            TypeError,
            IndexError,
            OverflowError,
            RecursionError,
        ):
            logger.warning("%s:%d: not an incident waiting for the log; skipped", path, n)
    return out


def store_spill(db: sqlite3.Connection, log: str | Path) -> int:
    """Stores the file's events in the log (db: a writer's connection to it), each once (one
    already there, stored before a kill removed the file, is not stored again), with ids from
    the log's mark; then removes the file. How many were stored."""
    waiting = read_spill(log)
    incidents = read_spilled_incidents(log)
    if not waiting and not incidents:
        spill_path(log).unlink(missing_ok=True)
        return 0
    runs = {r for (r,) in db.execute("SELECT id FROM runs")}
    placeholders = ", ".join("?" * (len(EVENT_COLUMNS) + 1))
    stored = 0
    db.execute("BEGIN IMMEDIATE")
    try:
        for run, e in waiting:
            row = event_row(e, run)
            same = (run, e.frame, e.person, e.zone, e.type, e.t)
            if (
                run not in runs
                or db.execute(f"SELECT 1 FROM events WHERE {_SAME}", same).fetchone()
            ):
                continue
            top = db.execute("SELECT MAX(id) FROM events").fetchone()[0]
            first = take(db, "events", 1, floor=int(top or 0) + 1)
            db.execute(
                f"INSERT INTO events(id, {', '.join(EVENT_COLUMNS)}) VALUES ({placeholders})",
                (first, *row),
            )
            stored += 1
        if incidents:
            upsert_incidents(db, incidents.values())
        db.execute("COMMIT")
    except BaseException:
        if db.in_transaction:
            db.execute("ROLLBACK")
        raise
    spill_path(log).unlink(missing_ok=True)
    if stored or incidents:
        logger.warning(
            "%s: %d event(s) and %d incident record(s) an earlier run could not "
            "store are stored now",
            log,
            stored,
            len(incidents),
        )
    return stored
