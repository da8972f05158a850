"""Ids that are never given again, on a real event log: event ids above every earlier one
after retention has emptied the log, acknowledgements that stay with their event, person ids
reserved before they are given (also while the log is locked, and across kill -9), zones left
open closed at every restart, and the live channel pushing the rows stored after a pruning."""

from __future__ import annotations

import asyncio
import json
import os
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from test_restart import WRITER, run_writer_until_killed

from stereopose.io.sinks.events import query_events
from stereopose.io.sinks.eventwriter import LockWaits, SqliteSink
from stereopose.io.sinks.spill import read_spill, spill_path
from stereopose.site.acks import AckStore
from stereopose.site.eventlog import EventLog, Filters
from stereopose.site.person_ids import PersonIds
from stereopose.site.restart import Resume
from stereopose.site.storage import RetentionSettings, StorageMaintainer
from stereopose.types import Event
from waiting import wait_until

DAY = 86400.0


def passing(n: int, first_t: float = 1.0) -> list[Event]:
    """n events that leave nothing open (approaches: no zone occupied, no alarm)."""
    return [
        Event(first_t + i, i, 1, "panel", "energized", "approach", first_t + i) for i in range(n)
    ]


def ids(db: Path) -> list[int]:
    con = sqlite3.connect(db)
    try:
        return [i for (i,) in con.execute("SELECT id FROM events ORDER BY id")]
    finally:
        con.close()


def prune_everything(out: Path, db: Path) -> int:
    """A retention pass ten days ahead, with a one-day retention: every event it may delete."""
    settings = RetentionSettings(event_retention_days=1.0)
    m = StorageMaintainer(out, event_log=db, settings=settings, now=lambda: time.time() + 10 * DAY)
    result = m.run_once()
    assert result.errors == 0, m.last_error
    return result.deleted["events"]


def test_ids_after_retention_emptied_the_log_are_above_every_earlier_id(tmp_path: Path) -> None:
    db = tmp_path / "events.sqlite"
    sink = SqliteSink(db)
    sink.write_events(passing(5))
    sink.close()
    before = ids(db)
    assert prune_everything(tmp_path, db) == 5 and ids(db) == []
    sink = SqliteSink(db)
    sink.write_events(passing(3))
    sink.write_events(passing(2, 10.0))
    sink.close()
    after = ids(db)
    assert len(after) == 5 and min(after) > max(before), f"ids given again: {after}"
    assert after == sorted(after)


def test_an_old_ack_never_shows_on_a_new_event(tmp_path: Path) -> None:
    db = tmp_path / "events.sqlite"
    sink = SqliteSink(db)
    sink.write_events(passing(4))
    acks = AckStore(db)  # one connection for the service's life, as the console holds it
    try:
        assert acks.ack(2, "olga") is not None
        assert prune_everything(tmp_path, db) == 4
        sink.write_events(passing(4, 20.0))
        log = EventLog(db)
        rows = log.query(Filters())
        assert len(rows) == 4 and all(r["ack"] is None for r in rows), rows
        assert acks.of(r["id"] for r in rows) == {}
        con = sqlite3.connect(db)
        assert con.execute("SELECT COUNT(*) FROM acks").fetchone() == (0,)  # pruned with it
        con.close()
        assert acks.ack(2, "olga") is None  # no event 2 any more, nor ever again
    finally:
        acks.close()
        sink.close()


OLD_LOG = """
CREATE TABLE runs (id INTEGER PRIMARY KEY, started REAL NOT NULL, site TEXT, source TEXT);
CREATE TABLE events (
    id INTEGER PRIMARY KEY, run INTEGER NOT NULL REFERENCES runs(id), t REAL NOT NULL,
    frame INTEGER NOT NULL, person INTEGER NOT NULL, zone TEXT NOT NULL, kind TEXT NOT NULL,
    type TEXT NOT NULL, onset_t REAL, joint TEXT, distance_m REAL, duration_s REAL, x REAL,
    y REAL, allowed INTEGER NOT NULL DEFAULT 0, lost INTEGER NOT NULL DEFAULT 0);
CREATE TABLE acks (event INTEGER PRIMARY KEY REFERENCES events(id), by TEXT NOT NULL,
    at REAL NOT NULL);
INSERT INTO runs VALUES (1, 1750000000.0, 'site', 'run');
INSERT INTO events(id, run, t, frame, person, zone, kind, type, onset_t)
    VALUES (3, 1, 1.0, 25, 7, 'panel', 'energized', 'approach', 1.0);
INSERT INTO acks VALUES (9, 'olga', 1750000100.0);  -- its event pruned by that version
"""


def test_a_log_of_an_earlier_version_gets_marks_above_its_events_and_acks(tmp_path: Path) -> None:
    db = tmp_path / "events.sqlite"
    con = sqlite3.connect(db)
    con.executescript(OLD_LOG)
    con.close()
    sink = SqliteSink(db)
    sink.write_events(passing(2, 5.0))
    sink.close()
    assert ids(db)[0] == 3 and min(ids(db)[1:]) > 9  # above the acknowledged id too
    rows = EventLog(db).query(Filters())
    assert [r["ack"] for r in rows] == [None, None, None]


def test_person_ids_are_reserved_before_they_are_given(tmp_path: Path) -> None:
    db = tmp_path / "events.sqlite"
    source = PersonIds(db, 5, block=4)

    def mark() -> int:
        con = sqlite3.connect(db)
        try:
            return con.execute("SELECT next FROM counters WHERE name = 'persons'").fetchone()[0]
        finally:
            con.close()

    for expected in range(5, 12):
        got = source.take()
        assert got == expected and mark() > got  # committed before it is handed out
    holder = sqlite3.connect(db, isolation_level=None)
    holder.execute("BEGIN IMMEDIATE")  # another process holds the log
    try:
        given = []
        while (pid := source.take()) is not None:
            given.append(pid)
        assert given and max(given) < mark() and source.error
    finally:
        holder.execute("ROLLBACK")
        holder.close()
    assert Resume.from_log(db).next_id > max(given)


def durable_exits(db: Path) -> set[tuple[str, int]]:
    """(zone, person) of the exits in the log or waiting beside it (not restart ones)."""
    if not db.exists():
        return set()
    stored = {
        (r["zone"], r["person"])
        for r in query_events(db)
        if r["type"] == "exit" and not r["restart"]
    }
    return stored | {(e.zone, e.person) for _, e in read_spill(db) if e.type == "exit"}


@pytest.mark.slow
def test_person_ids_are_never_below_the_reserved_range_after_kills(tmp_path: Path) -> None:
    """The log locked by another process while the writer gives ids, then kill -9: every id
    it gave was reserved, so the next start gives ids above them all; and every zone entered
    by an event the writer sent (stored, or waiting for the locked log) is closed at the next
    start."""
    db = tmp_path / "events.sqlite"
    given: set[int] = set()
    inside: set[tuple[str, int]] = set()  # by every event sent so far
    waited = 0  # rounds in which the lock held long enough for a new person to wait
    for round_ in range(3):
        # a kill between the sink taking a frame and the writer saying so: its exits are
        # stored (or waiting beside the log) though never reported; they count as sent
        inside -= durable_exits(db)
        resume = Resume.from_log(db)
        assert resume.next_id > max(given, default=0), "an id could name two people"
        env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
        proc = subprocess.Popen(
            [sys.executable, str(WRITER), str(db), str(100 + round_)],
            stdout=subprocess.PIPE,
            text=True,
            env=env,
        )
        holder = None
        lines: list[list[str]] = []
        try:
            locked_at = None
            for line in proc.stdout:
                lines.append(line.split())
                if lines[-1][0] == "given" and locked_at is None and len(lines) > 4:
                    holder = sqlite3.connect(db, isolation_level=None, timeout=10.0)
                    holder.execute("BEGIN IMMEDIATE")  # the log held while ids are given
                    locked_at, give_up = len(lines), time.monotonic() + 20.0
                # the writer is ahead of what is read here (the pipe holds lines): the lock
                # holds from some later line on; old code would give ids on and never wait
                if (
                    lines[-1] == ["waiting"]
                    or len(lines) > 100_000
                    or (locked_at and time.monotonic() > give_up)
                ):
                    break
        finally:
            proc.send_signal(signal.SIGKILL)
            rest, _ = proc.communicate(timeout=30)
            if holder is not None:
                holder.execute("ROLLBACK")
                holder.close()
        lines += [w.split() for w in rest.splitlines() if w.strip()]
        assert proc.returncode == -signal.SIGKILL, "the writer ended before it was killed"
        waited += ["waiting"] in lines
        round_given = {int(w[1]) for w in lines if w[0] == "given"}
        assert round_given and min(round_given) >= resume.next_id
        given |= round_given
        closing = {(w[2], int(w[3])) for w in lines if w[0] == "event" and w[5] == "1"}
        assert closing >= inside, f"left open: {inside - closing}"
        for w in lines:
            if w[0] == "sent" and w[1] == "enter":
                inside.add((w[2], int(w[3])))
            elif w[0] == "sent" and w[1] == "exit":
                inside.discard((w[2], int(w[3])))
    assert Resume.from_log(db).next_id > max(given)
    assert waited == 3, "the writer did not wait for an id: the lock did not hold"


@pytest.mark.slow
def test_ids_increase_and_open_zones_close_over_kill_cycles_with_retention(
    tmp_path: Path,
) -> None:
    """kill -9 at random moments (a fixed seed), retention emptying the log between the
    runs: event ids strictly increase over every cycle, and each restart closes exactly the
    zones the killed runs left occupied."""
    db = tmp_path / "events.sqlite"
    rng = np.random.default_rng(24)
    seen_top = 0  # the largest event id ever seen in the log
    kept: set[int] = set()  # the ids retention left: the enters still open
    inside: set[tuple[str, int]] = set()  # who is inside by every event committed so far
    for cycle in range(4):
        run_writer_until_killed(db, 240 + cycle, int(rng.integers(5, 80)))
        new_ids = [i for i in ids(db) if i not in kept]
        assert new_ids and min(new_ids) > seen_top, f"cycle {cycle}: an id given again"
        rows = query_events(db)  # by run, then t: the order each run stored them
        new = [r for r in rows if r["run"] == max(r["run"] for r in rows)]
        closing = {(r["zone"], r["person"]) for r in new if r["restart"]}
        assert closing == inside, f"cycle {cycle}: restart closed {closing}, open {inside}"
        for r in new:
            if r["type"] == "enter":
                inside.add((r["zone"], r["person"]))
            elif r["type"] == "exit":
                inside.discard((r["zone"], r["person"]))
        seen_top = max(ids(db))
        prune_everything(tmp_path, db)
        kept = set(ids(db))
        assert {(r["zone"], r["person"]) for r in query_events(db)} == inside


def test_the_live_hub_pushes_new_rows_after_the_log_was_emptied(
    tmp_path: Path, shared_data_dir: Path
) -> None:
    from stereopose.calibration.formats import load_calibration
    from stereopose.site.health.state import ServiceState
    from stereopose.site.live import HubSettings, LiveHub

    db = tmp_path / "events.sqlite"
    sink = SqliteSink(db)
    sink.write_events(passing(5))
    rig = load_calibration(shared_data_dir / "calib.toml")
    hub = LiveHub(rig, None, ServiceState(rig.names), EventLog(db), HubSettings(snapshot_hz=0.0))
    loop = asyncio.new_event_loop()
    try:
        hub.start()
        sub = hub.subscribe(loop, "otto", privileged=True)
        assert sub is not None
        pushed: list[int] = []
        kinds: list[str] = []

        def events_pushed() -> list[int]:
            for message in sub.take():
                kind, data = message.decode().split("\n")[:2]
                kinds.append(kind)
                if kind == "event: event":
                    pushed.append(json.loads(data.removeprefix("data: "))["id"])
            return pushed

        # the hub's first round (the zones sent again) has taken where the log ends
        wait_until(
            lambda: events_pushed() == [] and kinds.count("event: zones") >= 2,
            "the live channel's first round",
        )
        sink.write_events(passing(1, 9.0))
        wait_until(lambda: len(events_pushed()) == 1, "the event stored after the start")
        assert prune_everything(tmp_path, db) == 6
        sink.write_events(passing(3, 30.0))
        wait_until(lambda: len(events_pushed()) >= 4, "the events stored after the pruning")
        sink.write_events(passing(1, 40.0))
        wait_until(lambda: len(events_pushed()) >= 5, "one more")
        assert len(pushed) == 5 and pushed[1:] == ids(db)  # each once, in order
    finally:
        hub.close()
        loop.close()
        sink.close()


def test_events_waiting_for_a_locked_log_are_kept_and_stored_once_at_the_next_start(
    tmp_path: Path,
) -> None:
    """An enter sent while the log was locked, then the process gone without closing (as
    after kill -9): the next start closes its zone and stores it in the log, once."""
    db = tmp_path / "events.sqlite"
    first = SqliteSink(db, waits=LockWaits(busy_s=0.01))
    holder = sqlite3.connect(db, isolation_level=None)
    holder.execute("BEGIN IMMEDIATE")
    try:
        first.write_events([Event(1.0, 25, 7, "panel", "energized", "enter", 1.0)])
        assert first.pending and spill_path(db).is_file()
    finally:
        holder.execute("ROLLBACK")
        holder.close()
    kept = spill_path(db).read_text()
    first.db.close()  # gone without a word, its event still waiting
    assert Resume.from_log(db).open_zones == {"panel": (7,)}
    SqliteSink(db).close()
    assert [(r["type"], r["person"]) for r in query_events(db)] == [("enter", 7)]
    assert not spill_path(db).exists()
    spill_path(db).write_text(kept)  # as if killed after storing it, before removing the file
    SqliteSink(db).close()
    assert len(query_events(db)) == 1 and not spill_path(db).exists()


def test_a_log_killed_before_its_tables_were_committed_is_a_fresh_start(tmp_path: Path) -> None:
    db = tmp_path / "events.sqlite"
    db.touch()  # what sqlite3.connect leaves when the process dies right after it
    assert Resume.from_log(db).next_id == 1
    con = sqlite3.connect(db)
    con.execute("PRAGMA journal_mode=WAL")  # or the header written, still no table
    con.close()
    assert Resume.from_log(db).runs == 0
    SqliteSink(db).close()
    assert Resume.from_log(db).runs == 1


def test_incidents_waiting_for_a_locked_log_are_kept_and_taken_back_at_the_next_start(
    tmp_path: Path,
) -> None:
    """An incident raised (and published) while the log was locked, then the process gone as
    after kill -9: the next start takes it back open, and stores its latest record, once."""
    from stereopose.alarms import AlarmSettings, IncidentBook
    from stereopose.io.sinks.incidents import IncidentFilters, query_incidents
    from stereopose.io.sinks.spill import read_spilled_incidents

    db = tmp_path / "events.sqlite"
    first = SqliteSink(db, wall_start=1_000.0, waits=LockWaits(busy_s=0.01))
    book = IncidentBook(AlarmSettings(), next_id=iter(range(1, 100)).__next__)
    enter = Event(1.0, 25, 7, "panel", "energized", "enter", 1.0)
    up = book.update([enter], 1.0)
    holder = sqlite3.connect(db, isolation_level=None)
    holder.execute("BEGIN IMMEDIATE")
    try:
        first.put_incidents([c.incident for c in up.changes])
        first.write_events([enter])
        again = book.update([Event(2.0, 50, 7, "panel", "energized", "enter", 2.0)], 2.0)
        first.put_incidents([c.incident for c in again.changes])
        first.write_events([])
        spilled = read_spilled_incidents(db)
        assert list(spilled) == [up.incidents[0]] and spilled[up.incidents[0]][1] == 1_000.0
        assert spilled[up.incidents[0]][0].occurrences == 2  # the latest record wins
    finally:
        holder.execute("ROLLBACK")
        holder.close()
    first.db.close()  # gone without a word, its incident still waiting
    resumed = Resume.from_log(db)
    assert [(r.id, r.state, r.occurrences) for r, _ in resumed.incidents] == [
        (up.incidents[0], "active", 2)
    ]
    assert [e.type for _, e in read_spill(db)] == ["enter"]  # the events read as before
    SqliteSink(db).close()
    stored = query_incidents(db, IncidentFilters())
    assert [(i["id"], i["occurrences"]) for i in stored] == [(up.incidents[0], 2)]
    assert stored[0]["first_wall_t"] == 1_001.0
    assert not spill_path(db).exists()
