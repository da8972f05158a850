"""Bounded storage: one maintainer thread deletes what is past its retention, keeps the pose
segments and event clips under a byte cap, and prunes old events from the SQLite event log.

The one place that deletes (as Frigate's StorageMaintainer): every `interval_s` a pass
1. deletes pose segments (`poses/*.jsonl.gz`) older than `retention_days` and clips
   (`clips/*.mp4`) older than `clip_retention_days`, by the time of their last write;
2. then, while segments and clips together hold more than `max_bytes`, the oldest of them;
3. deletes events older than `event_retention_days` from the event log, in short
   transactions of `event_batch` rows, and their acknowledgements with them; a log locked by
   its writer is tried again next pass. The rows that keep a zone occupied or a behaviour
   alarm open (site.restart) stay until they are closed, however old, so that a restart
   still closes them; and ids are never given again (the log's high-water marks,
   io.sinks.eventdb, are never lowered).
The newest segment (the one being written) and a clip being written (`*.part.mp4` written to
in the last hour) are never deleted; nor is any file the sinks did not name so. A failure
(permission, a file gone meanwhile) is logged and counted, and the pass goes on; the thread
never stops on an error. Time comes from `now` (Unix seconds), so tests need no sleep.
"""

from __future__ import annotations

import contextlib
import logging
import sqlite3
import stat
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from stereopose.checks import DAY_S
from stereopose.io.datafolder import CLIPS_DIR, POSES_DIR
from stereopose.io.settings import check_settings, ranged
from stereopose.io.sinks.clips import CLIP_SUFFIX, PART_SUFFIX
from stereopose.io.sinks.eventdb import connect_writer
from stereopose.io.sinks.segments import SEGMENT_SUFFIX
from stereopose.site.restart import open_rows

__all__ = ["KINDS", "PassResult", "RetentionSettings", "StorageMaintainer"]

logger = logging.getLogger(__name__)

KINDS = ("segments", "clips", "events")
_MAX_DAYS = 36500.0
_WRITING_S = 3600.0  # a `.part` clip written to more recently than this is being written
_MAX_BATCHES = 100  # per pass: a large backlog is pruned over several passes


@dataclass(frozen=True, kw_only=True)
class RetentionSettings:
    """How long each kind is kept and how much the files may hold (keys of `[storage]`).

    retention_days: pose segments; clip_retention_days: event clips; event_retention_days:
    events of the SQLite log; max_bytes: segments and clips together (0: no cap);
    interval_s: between passes; event_batch: events deleted per transaction; busy_s: the
    longest a pass waits for the event log's lock.
    """

    retention_days: float = ranged(7.0, gt=0.0, le=_MAX_DAYS)
    clip_retention_days: float = ranged(30.0, gt=0.0, le=_MAX_DAYS)
    event_retention_days: float = ranged(365.0, gt=0.0, le=_MAX_DAYS)
    max_bytes: int = ranged(0, ge=0, le=2**62, integer=True)
    interval_s: float = ranged(60.0, gt=0.0, le=DAY_S)
    event_batch: int = ranged(500, ge=1, le=100_000, integer=True)
    busy_s: float = ranged(0.05, ge=0.0, le=5.0)

    def __post_init__(self) -> None:
        check_settings(self, "storage")


@dataclass
class PassResult:
    """What one pass did: deleted (kind -> files, or events), freed_bytes (kind -> bytes),
    usage (kind -> bytes afterwards), errors (how many failures), events_locked (the log was
    busy: pruning waits for the next pass), over_cap (still above max_bytes: only files that
    may not be deleted are left)."""

    deleted: dict[str, int] = field(default_factory=lambda: dict.fromkeys(KINDS, 0))
    freed_bytes: dict[str, int] = field(default_factory=lambda: dict.fromkeys(KINDS, 0))
    usage: dict[str, int] = field(default_factory=lambda: dict.fromkeys(KINDS, 0))
    errors: int = 0
    events_locked: bool = False
    over_cap: bool = False


@dataclass
class _File:
    kind: str
    path: Path
    size: int
    mtime: float
    keep: bool = False  # being written: never deleted


class StorageMaintainer:
    """The retention thread of `out_dir` (its `poses/` and `clips/`) and of `event_log`.

    `run_once()` makes one pass now; `start()` runs passes every interval_s on a thread until
    `stop()`. `health()` is what the service reports: bytes per kind, passes, deletions and
    errors so far.
    """

    def __init__(
        self,
        out_dir: str | Path,
        *,
        event_log: str | Path | None = None,
        settings: RetentionSettings | None = None,
        now: Callable[[], float] = time.time,
    ) -> None:
        self.out_dir = Path(out_dir)
        self.event_log = None if event_log is None else Path(event_log)
        self.settings = settings or RetentionSettings()
        self.now = now
        self.passes = self.errors = self.events_locked = 0
        self.last_error: str | None = None
        self.last: PassResult | None = None
        self.deleted = dict.fromkeys(KINDS, 0)
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    # -- the thread --------------------------------------------------------------------------

    def start(self) -> None:
        """Run a pass now and then every interval_s, on a thread of its own."""
        if self._thread is not None:
            return
        self._stop.clear()
        self._thread = threading.Thread(target=self._loop, name="storage", daemon=True)
        self._thread.start()

    def stop(self, timeout_s: float = 5.0) -> bool:
        """Stop the thread (a pass under way ends first); whether it has stopped."""
        self._stop.set()
        thread, self._thread = self._thread, None
        if thread is None:
            return True
        thread.join(timeout_s)
        return not thread.is_alive()

    def _loop(self) -> None:
        while not self._stop.is_set():
            try:
                self.run_once()
            except Exception as e:  # a bug must not end retention: logged, counted, next pass
                logger.exception("storage: pass failed")
                self._error(f"pass failed: {e}")
            self._stop.wait(self.settings.interval_s)

    # -- one pass ----------------------------------------------------------------------------

    def run_once(self) -> PassResult:
        """One pass: retention, the cap, the event log; what it did."""
        with self._lock:
            result = PassResult()
            now = self.now()
            files = self._scan(result)
            files = self._expire(files, now, result)
            files = self._cap(files, result)
            self._prune_events(now, result)
            for f in files:
                result.usage[f.kind] += f.size
            result.usage["events"] = self._log_bytes()
            self.passes += 1
            for kind in KINDS:
                self.deleted[kind] += result.deleted[kind]
            self.last = result
        self._report(result)
        return result

    def _scan(self, result: PassResult) -> list[_File]:
        """The segments and clips on disk; the newest segment and clips being written kept."""
        now = self.now()
        segments = self._list(self.out_dir / POSES_DIR, SEGMENT_SUFFIX, "segments", result)
        clips = self._list(self.out_dir / CLIPS_DIR, CLIP_SUFFIX, "clips", result)
        if segments:  # the one being written: the newest by name (start) and by last write
            max(segments, key=lambda f: f.path.name).keep = True
            max(segments, key=lambda f: (f.mtime, f.path.name)).keep = True
        for c in clips:
            c.keep = c.path.name.endswith(PART_SUFFIX) and now - c.mtime < _WRITING_S
        return segments + clips

    def _list(self, folder: Path, suffix: str, kind: str, result: PassResult) -> list[_File]:
        try:
            entries = list(folder.iterdir())
        except FileNotFoundError:
            return []
        except OSError as e:
            self._failed(result, f"{folder}: cannot list {kind}: {e.strerror}")
            return []
        out = []
        for path in entries:
            if not path.name.endswith(suffix):
                continue
            try:
                st = path.lstat()
            except FileNotFoundError:
                continue  # gone meanwhile (a clip renamed when done is listed again next pass)
            except OSError as e:
                self._failed(result, f"{path}: cannot read: {e.strerror}")
                continue
            if stat.S_ISREG(st.st_mode):  # links and folders are not ours to delete
                out.append(_File(kind, path, st.st_size, st.st_mtime))
        return out

    def _expire(self, files: list[_File], now: float, result: PassResult) -> list[_File]:
        """Delete what is past its retention; the files left."""
        days = {
            "segments": self.settings.retention_days,
            "clips": self.settings.clip_retention_days,
        }
        left = []
        for f in files:
            if not f.keep and f.mtime < now - days[f.kind] * DAY_S and self._delete(f, result):
                continue
            left.append(f)
        return left

    def _cap(self, files: list[_File], result: PassResult) -> list[_File]:
        """Delete the oldest files while the total is above max_bytes; the files left."""
        cap = self.settings.max_bytes
        total = sum(f.size for f in files)
        if not cap or total <= cap:
            return files
        gone: set[int] = set()
        for i in sorted(range(len(files)), key=lambda i: (files[i].mtime, files[i].path.name)):
            if total <= cap:
                break
            f = files[i]
            if not f.keep and self._delete(f, result):
                total -= f.size
                gone.add(i)
        result.over_cap = total > cap
        return [f for i, f in enumerate(files) if i not in gone]

    def _delete(self, f: _File, result: PassResult) -> bool:
        """Delete one file; whether it is gone (a file already gone counts as a failure)."""
        try:
            f.path.unlink()
        except FileNotFoundError:
            self._failed(result, f"{f.path}: gone before it could be deleted")
            return True
        except OSError as e:
            self._failed(result, f"{f.path}: cannot delete: {e.strerror}")
            return False
        result.deleted[f.kind] += 1
        result.freed_bytes[f.kind] += f.size
        return True

    # -- the event log -----------------------------------------------------------------------

    def _prune_events(self, now: float, result: PassResult) -> None:
        """Delete events older than their retention, in short transactions; a locked log is
        left for the next pass. An event's time is its run's start plus its t."""
        path = self.event_log
        if path is None or not path.is_file():
            return
        cutoff = now - self.settings.event_retention_days * DAY_S
        try:
            # the writer's settings (WAL, synchronous), the marks raised before any delete
            db = connect_writer(path, self.settings.busy_s)
        except sqlite3.OperationalError as e:
            if "locked" in str(e) or "busy" in str(e):
                result.events_locked = True
                self.events_locked += 1
            else:
                self._failed(result, f"{path}: cannot open the event log: {e}")
            return
        except sqlite3.Error as e:
            self._failed(result, f"{path}: cannot open the event log: {e}")
            return
        try:
            runs = db.execute(
                "SELECT id, started FROM runs WHERE started < ?", (cutoff,)
            ).fetchall()
            keep = open_rows(db) if runs else set()
            acks = bool(
                db.execute(
                    "SELECT 1 FROM sqlite_master WHERE type = 'table' AND name = 'acks'"
                ).fetchone()
            )
            for run, started in runs:
                if not self._prune_run(db, run, cutoff - started, result, keep, acks):
                    break
        except sqlite3.OperationalError as e:
            self._busy_or_failed(db, result, e)
        except sqlite3.Error as e:
            self._failed(result, f"{path}: cannot prune events: {e}")
        finally:
            db.close()

    def _prune_run(
        self,
        db: sqlite3.Connection,
        run: int,
        before_t: float,
        r: PassResult,
        keep: set[int],
        acks: bool,
    ) -> bool:
        """Delete one run's events with t < before_t, batch by batch, their acknowledgements
        with them (an ack names one event for ever), but never `keep` (the rows that hold a
        zone occupied or an alarm open: a restart must still see them to close them); False
        when this pass has deleted its share (the rest waits for the next pass)."""
        batch, after = self.settings.event_batch, 0
        while True:
            if r.deleted["events"] >= _MAX_BATCHES * batch:
                return False
            db.execute("BEGIN IMMEDIATE")
            found = [
                i
                for (i,) in db.execute(
                    "SELECT id FROM events WHERE run = ? AND t < ? AND id > ? ORDER BY id LIMIT ?",
                    (run, before_t, after, batch),
                )
            ]
            gone = [(i,) for i in found if i not in keep]
            db.executemany("DELETE FROM events WHERE id = ?", gone)
            if acks:
                db.executemany("DELETE FROM acks WHERE event = ?", gone)
            db.execute("COMMIT")
            r.deleted["events"] += len(gone)
            if len(found) < batch:
                return True
            after = found[-1]

    def _busy_or_failed(self, db: sqlite3.Connection, result: PassResult, e: sqlite3.Error) -> None:
        try:
            if db.in_transaction:
                db.execute("ROLLBACK")
        except sqlite3.Error:  # closed right after
            pass
        text = str(e)
        if "locked" in text or "busy" in text:
            result.events_locked = True
            self.events_locked += 1
            logger.info(
                "storage: %s is locked; its old events are pruned next pass", self.event_log
            )
        else:
            self._failed(result, f"{self.event_log}: cannot prune events: {text}")

    def _log_bytes(self) -> int:
        """The event log's size on disk, its WAL included."""
        if self.event_log is None:
            return 0
        total = 0
        for suffix in ("", "-wal", "-shm"):
            with contextlib.suppress(OSError):  # not there (no WAL now, or no log yet)
                total += self.event_log.with_name(self.event_log.name + suffix).stat().st_size
        return total

    # -- reporting ---------------------------------------------------------------------------

    def _failed(self, result: PassResult, message: str) -> None:
        result.errors += 1
        self._error(message)
        logger.warning("storage: %s", message)

    def _error(self, message: str) -> None:
        self.errors += 1
        self.last_error = message

    def _report(self, r: PassResult) -> None:
        mib = 2**20
        if any(r.deleted.values()):
            logger.info(
                "storage: deleted %d segment(s) (%.1f MiB), %d clip(s) (%.1f MiB), %d event(s); "
                "now %.1f MiB of segments, %.1f MiB of clips, %.1f MiB of events",
                r.deleted["segments"],
                r.freed_bytes["segments"] / mib,
                r.deleted["clips"],
                r.freed_bytes["clips"] / mib,
                r.deleted["events"],
                r.usage["segments"] / mib,
                r.usage["clips"] / mib,
                r.usage["events"] / mib,
            )
        if r.over_cap:
            logger.warning(
                "storage: %.1f MiB of segments and clips, above max_bytes (%.1f MiB): only "
                "files being written are left",
                (r.usage["segments"] + r.usage["clips"]) / mib,
                self.settings.max_bytes / mib,
            )

    def usage(self) -> dict[str, int]:
        """Bytes per kind after the last pass (zeros before the first)."""
        last = self.last
        return dict(last.usage) if last else dict.fromkeys(KINDS, 0)

    def health(self) -> dict:
        """The storage part of the service's health: bytes per kind, passes, deletions so far,
        errors (with the last one), how often the event log was found locked."""
        last = self.last
        return {
            "usage_bytes": self.usage(),
            "max_bytes": self.settings.max_bytes,
            "over_cap": bool(last and last.over_cap),
            "passes": self.passes,
            "deleted": dict(self.deleted),
            "errors": self.errors,
            "last_error": self.last_error,
            "events_locked": self.events_locked,
        }
