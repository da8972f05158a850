"""The event log as the console reads it: filtered pages of events, newest first, each with
its wall time, its level, its acknowledgement and its clips.

An event's wall time is its run's `wall_start` + t (the run's start time for a log written
before wall_start was recorded). Its clips are the MP4 files of `<output>/clips` named from
it (io.sinks.clips.clip_name: the event's UTC second, person, zone, any camera). Reads go
through a read-only connection opened per query, so they never hold up the frame loop; a
read that meets a transient error (the log locked, or its WAL being recovered by a process
starting after a kill) is tried again before it is reported. Event ids are never given
again (io.sinks.eventdb), so "the events after id N" are the ones stored since.
"""

from __future__ import annotations

import math
import re
import sqlite3
import threading
import time
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from urllib.request import pathname2url

from stereopose.alarms.levels import level as alarm_level
from stereopose.behaviour.definitions import ALARM_TYPES as BEHAVIOUR_ALARMS
from stereopose.errors import StereoposeError
from stereopose.io.records import EVENT_COLUMNS
from stereopose.io.sinks.clip_parts import CLIP_SUFFIX, PART_SUFFIX, part_name
from stereopose.io.sinks.eventdb import reading, transient
from stereopose.io.sinks.incidents import changes_after, last_change

# a camera down, and the behaviour rules' alarms (a person down, alone, immobile, ...)
ALARM_TYPES = frozenset({"camera_down", "service_stalled"}) | BEHAVIOUR_ALARMS
WARNING_TYPES = frozenset({"dwell", "left_work_area", "calibration_drift"})
MAX_LIMIT = 1000
DEFAULT_LIMIT = 100
_STAMP = re.compile(r"\d{8}-\d{6}_")
_CLIPS_CACHE_S = 1.0


class LogError(StereoposeError):
    """The event log cannot be read."""


def level(kind: str, type_: str) -> str:
    """alarm: entering or approaching an energized zone, a camera down, a behaviour alarm
    (person_down, lone_worker, work_position, immobile, overreach);
    warning: dwell, leaving the work area, calibration drift, entering a restricted zone;
    info: the rest. The incidents' own table (alarms.levels), so the log and the incident
    book never disagree on what raises an incident."""
    return alarm_level(kind, type_)


@dataclass(frozen=True)
class Filters:
    """since/until: wall time (Unix seconds); before_id/after_id: id bounds (exclusive)."""

    since: float | None = None
    until: float | None = None
    person: int | None = None
    zone: str | None = None
    type: str | None = None
    ticket: str | None = None
    limit: int = DEFAULT_LIMIT
    before_id: int | None = None
    after_id: int | None = None


def parse_time(value: str, name: str) -> float:
    """Unix seconds from epoch seconds or ISO 8601 (a time without zone is UTC)."""
    text = value.strip()
    try:
        t = float(text)
    except ValueError:
        try:
            d = datetime.fromisoformat(text.replace("Z", "+00:00"))
        except ValueError:
            raise ValueError(
                f"{name}: expected Unix seconds or an ISO 8601 time, got {value!r}"
            ) from None
        if d.tzinfo is None:
            d = d.replace(tzinfo=UTC)
        t = d.timestamp()
    if not math.isfinite(t):
        raise ValueError(f"{name}: expected a finite time, got {value!r}")
    return t


class EventLog:
    """Reads of the event log at `path`; clips from `clips_dir` (None: none)."""

    def __init__(self, path: str | Path, clips_dir: str | Path | None = None) -> None:
        self.path = Path(path)
        self.clips_dir = Path(clips_dir) if clips_dir is not None else None
        self._lock = threading.Lock()
        self._clips: tuple[float, dict[str, list[str]]] | None = None

    def _connect(self) -> sqlite3.Connection | None:
        """A read-only connection (never `immutable`: the log changes under it; WAL gives each
        query a consistent snapshot of what was committed)."""
        if not self.path.is_file():
            return None
        try:
            db = sqlite3.connect(
                f"file:{pathname2url(str(self.path.resolve()))}?mode=ro", uri=True, timeout=0.5
            )
            db.execute("PRAGMA busy_timeout = 500")
            return db
        except sqlite3.Error as e:
            raise LogError(f"{self.path}: cannot read the event log: {e}") from None

    def query(self, f: Filters) -> list[dict]:
        """The events matching `f`, newest first (by id), at most f.limit."""
        where, args = [], []
        wall = "(COALESCE(r.wall_start, r.started) + e.t)"
        for sql, value in (
            ("e.person = ?", f.person),
            ("e.zone = ?", f.zone),
            ("e.type = ?", f.type),
            ("e.ticket = ?", f.ticket),
            (f"{wall} >= ?", f.since),
            (f"{wall} <= ?", f.until),
            ("e.id < ?", f.before_id),
            ("e.id > ?", f.after_id),
        ):
            if value is not None:
                where.append(sql)
                args.append(value)
        order = "ASC" if f.after_id is not None and f.before_id is None else "DESC"
        rows = self._select(where, args, f"ORDER BY e.id {order} LIMIT ?", [f.limit])
        if order == "ASC":
            rows.reverse()
        return rows

    def after(self, last_id: int, limit: int = 500) -> list[dict]:
        """Events with id > last_id, oldest first (the live tail)."""
        return self._select(["e.id > ?"], [last_id], "ORDER BY e.id ASC LIMIT ?", [limit])

    def last_id(self) -> int:
        """The largest event id stored (0: none; the file not there yet). Ids are never given
        again, so the events after it are exactly the ones stored later, however many were
        pruned. A LogError when the log cannot be read (not 0: a tail from 0 would send every
        stored event again)."""
        try:
            return reading(self._last_id)
        except sqlite3.DatabaseError as e:
            raise LogError(f"{self.path}: cannot read the event log: {e}") from None

    def incident_changes_after(self, seq: int, limit: int = 200) -> list[dict]:
        """The incidents changed after change `seq`, in change order: {"seq", "incident"}
        (io.sinks.incidents.changes_after); a LogError when the log cannot be read."""
        try:
            return changes_after(self.path, seq, limit)
        except sqlite3.DatabaseError as e:
            raise LogError(f"{self.path}: cannot read the incidents: {e}") from None

    def last_incident_change(self) -> int:
        """The last change number given to an incident (0: none)."""
        try:
            return last_change(self.path)
        except sqlite3.DatabaseError as e:
            raise LogError(f"{self.path}: cannot read the incidents: {e}") from None

    def _last_id(self) -> int:
        db = self._connect()
        if db is None:
            return 0
        try:
            tables = {r[0] for r in db.execute("SELECT name FROM sqlite_master")}
            if "events" not in tables:
                return 0
            row = db.execute("SELECT MAX(id) FROM events").fetchone()
        except sqlite3.DatabaseError as e:
            if transient(e):
                raise
            raise LogError(f"{self.path}: cannot read the event log: {e}") from None
        finally:
            db.close()
        return int(row[0] or 0)

    def _select(self, where: list[str], args: list, tail: str, tail_args: list) -> list[dict]:
        try:
            return reading(lambda: self._select_once(where, args, tail, tail_args))
        except sqlite3.DatabaseError as e:
            raise LogError(f"{self.path}: cannot read the event log: {e}") from None

    def _select_once(self, where: list[str], args: list, tail: str, tail_args: list) -> list[dict]:
        db = self._connect()
        if db is None:
            return []
        try:
            have = {r[1] for r in db.execute("PRAGMA table_info(events)")}
            runs = {r[1] for r in db.execute("PRAGMA table_info(runs)")}
            if not have or ("ticket" not in have and any("e.ticket" in w for w in where)):
                return []  # no events; or a log older than tickets: none of a ticket
            cols = ", ".join(
                f"e.{c}" if c in have else ("0" if c == "restart" else "NULL")
                for c in EVENT_COLUMNS
            )
            start = "COALESCE(r.wall_start, r.started)" if "wall_start" in runs else "r.started"
            acks = bool(
                db.execute(
                    "SELECT 1 FROM sqlite_master WHERE type = 'table' AND name = 'acks'"
                ).fetchone()
            )
            ack_cols = "a.by, a.at" if acks else "NULL, NULL"
            ack_join = "LEFT JOIN acks a ON a.event = e.id" if acks else ""
            sql = (
                f"SELECT e.id, {start}, {cols}, {ack_cols} FROM events e "
                f"JOIN runs r ON r.id = e.run {ack_join}"
            )
            if where:
                sql += " WHERE " + " AND ".join(
                    w.replace("r.wall_start", "r.started") if "wall_start" not in runs else w
                    for w in where
                )
            rows = db.execute(f"{sql} {tail}", [*args, *tail_args]).fetchall()
        except sqlite3.DatabaseError as e:
            if transient(e):  # tried again by _select
                raise
            raise LogError(f"{self.path}: cannot read the event log: {e}") from None
        finally:
            db.close()
        return [self._item(r) for r in rows]

    def _item(self, row: tuple) -> dict:
        event_id, start, *values = row
        rec = dict(zip(EVENT_COLUMNS, values[: len(EVENT_COLUMNS)], strict=True))
        by, at = values[len(EVENT_COLUMNS) :]
        wall_t = float(start or 0.0) + float(rec["t"])
        item = {
            "id": event_id,
            "t": rec["t"],
            "wall_t": round(wall_t, 3),
            "time": datetime.fromtimestamp(wall_t, UTC)
            .isoformat(timespec="milliseconds")
            .replace("+00:00", "Z"),
            "frame": rec["frame"],
            "person": rec["person"],
            "zone": rec["zone"],
            "kind": rec["kind"],
            "type": rec["type"],
            "level": level(rec["kind"], rec["type"]),
            "camera": rec["camera"],
        }
        for key, value in rec.items():  # every other column of the log, as stored
            if key not in item and key != "run":
                item[key] = bool(value) if key in ("allowed", "lost", "restart") else value
        item["run"] = rec["run"]
        item["ack"] = {"by": by, "at": at} if by is not None else None
        # a behaviour alarm's clips too (no zone: named "x" in its place, as clip_name does)
        person = rec["person"]
        item["clips"] = self.clips_of(wall_t, person, rec["zone"] or "") if person >= 0 else []
        return item

    # -- clips -----------------------------------------------------------------------------

    def clips_of(self, wall_t: float, person: int, zone: str) -> list[str]:
        """/api/clips/ URLs of the clips named from an event at wall_t: `<UTC second>_<person>_
        <zone>_<camera>.mp4` (one second either side, for the rounding of the run's start)."""
        index = self._clip_index()
        if not index:
            return []
        who = f"_{part_name(str(person))}_{part_name(zone)}_"
        for dt in (0, -1, 1):
            stamp = datetime.fromtimestamp(math.floor(wall_t) + dt, UTC)
            prefix = stamp.strftime("%Y%m%d-%H%M%S") + who
            found = [n for n in index.get(prefix[:15], ()) if n.startswith(prefix)]
            if found:
                return [f"/api/clips/{name}" for name in sorted(found)]
        return []

    def _clip_index(self) -> dict[str, list[str]]:
        """The finished clips by their names' UTC second (read again after a second)."""
        if self.clips_dir is None:
            return {}
        now = time.monotonic()
        with self._lock:
            if self._clips is not None and now - self._clips[0] < _CLIPS_CACHE_S:
                return self._clips[1]
        index: dict[str, list[str]] = {}
        try:
            names = [e.name for e in self.clips_dir.iterdir()]
        except OSError:
            names = []
        for name in names:
            if name.endswith(CLIP_SUFFIX) and not name.endswith(PART_SUFFIX) and _STAMP.match(name):
                index.setdefault(name[:15], []).append(name)
        with self._lock:
            self._clips = (now, index)
        return index
