"""Restart safety on a real event log: a writer process killed with SIGKILL at random moments,
then resumed: every committed event readable, ids never reused, open zones closed by exits
marked restart; and the log's additions read by the existing readers, old logs upgraded."""

from __future__ import annotations

import os
import signal
import sqlite3
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from stereopose.config import Config
from stereopose.errors import StereoposeError
from stereopose.io.records import event_from_record
from stereopose.io.sinks.events import query_events
from stereopose.io.sinks.eventwriter import SqliteSink
from stereopose.site.restart import Resume
from stereopose.tracking.memory import make_memory
from stereopose.tracking.tracker import Tracker
from stereopose.types import Event

WRITER = Path(__file__).with_name("restart_writer.py")


def run_writer_until_killed(db: Path, seed: int, commits: int) -> list[list[str]]:
    """The writer's report lines up to its kill, after `commits` committed frames' events."""
    proc = subprocess.Popen(
        [sys.executable, str(WRITER), str(db), str(seed)],
        stdout=subprocess.PIPE,
        text=True,
        env={**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)},
    )
    lines, events = [], 0
    try:
        for line in proc.stdout:  # every line is flushed; the pipe ends when the writer does
            lines.append(line.split())
            events += lines[-1][0] == "event"
            if events >= commits:
                break
    finally:
        proc.send_signal(signal.SIGKILL)
        rest, _ = proc.communicate(timeout=30)  # what it said before dying counts too
    lines += [line.split() for line in rest.splitlines() if line.strip()]
    assert proc.returncode == -signal.SIGKILL, "the writer ended before it was killed"
    return lines


def occupancy(rows: list[dict]) -> set[tuple[str, int]]:
    inside: set[tuple[str, int]] = set()
    for r in rows:
        if r["type"] == "enter":
            inside.add((r["zone"], r["person"]))
        elif r["type"] == "exit":
            inside.discard((r["zone"], r["person"]))
    return inside


@pytest.mark.slow
@pytest.mark.parametrize("seed", [1, 2])
def test_kill_9_at_random_moments_then_resume(tmp_path: Path, seed: int) -> None:
    db = tmp_path / "events.sqlite"
    rng = np.random.default_rng(seed)
    given: set[int] = set()
    committed: list[tuple] = []
    open_before: list[set[tuple[str, int]]] = []
    for round_ in range(3):
        resume = Resume.from_log(db)
        assert resume.next_id > max(given, default=0), "an id could name two people"
        open_before.append({(z, p) for z, ids in resume.open_zones.items() for p in ids})
        if round_:
            assert resume.crashed
        lines = run_writer_until_killed(db, seed * 10 + round_, int(rng.integers(5, 150)))
        assert lines[0] == ["next", str(resume.next_id)]
        given |= {int(w[1]) for w in lines if w[0] == "given"}
        committed += [tuple(w[1:]) for w in lines if w[0] == "event"]
        assert min(int(w[1]) for w in lines if w[0] == "given") >= resume.next_id
    final = Resume.from_log(db)
    assert final.next_id > max(given)
    ro = sqlite3.connect(f"file:{db}?mode=ro", uri=True)
    assert ro.execute("PRAGMA integrity_check").fetchone() == ("ok",)
    ro.close()
    rows = query_events(db)
    stored = {
        (r["type"], r["zone"], str(r["person"]), str(r["frame"]), str(r["restart"])) for r in rows
    }
    assert set(committed) <= stored, "a committed event was lost"
    # each run opened with a restart-marked exit for exactly who was inside when the last died
    for run, was_open in zip(sorted({r["run"] for r in rows}), open_before, strict=False):
        restarted = {(r["zone"], r["person"]) for r in rows if r["run"] == run and r["restart"]}
        assert restarted == was_open
        assert all(r["type"] == "exit" for r in rows if r["restart"])
    # an id names one person: all its events in one run (but the exit closing it at a restart)
    for pid in {r["person"] for r in rows}:
        assert len({r["run"] for r in rows if r["person"] == pid and not r["restart"]}) == 1
    assert {(z, p) for z, ids in final.open_zones.items() for p in ids} == occupancy(rows)


def test_a_clean_close_is_not_a_crash_and_closed_zones_stay_closed(tmp_path: Path) -> None:
    db = tmp_path / "events.sqlite"
    sink = SqliteSink(db, first_id=1)
    sink.write_events(
        [
            Event(1.0, 25, 1, "panel", "energized", "enter", 1.0, position=(0.5, 2.0)),
            Event(1.0, 25, 2, "panel", "energized", "enter", 1.0, allowed=True),
            Event(2.0, 50, 2, "panel", "energized", "exit", 2.0),
            Event(2.0, 50, 3, "cage", "restricted", "enter", 2.0),
        ]
    )
    sink.close()
    resume = Resume.from_log(db)
    assert not resume.crashed and resume.runs == 1
    assert resume.open_zones == {"panel": (1,), "cage": (3,)}
    closing = resume.closing_events(0.5, 0)
    assert [(e.type, e.zone, e.person, e.restart) for e in closing] == [
        ("exit", "panel", 1, True),
        ("exit", "cage", 3, True),
    ]
    assert closing[0].position == (0.5, 2.0) and closing[0].kind == "energized"
    again = SqliteSink(db, first_id=resume.next_id)
    again.write_events(closing)
    again.close()
    assert Resume.from_log(db).open_zones == {}
    assert [event_from_record(r) for r in query_events(db)][-2:] == closing


def behaviour(t: float, person: int, type_: str, rule: str) -> Event:
    return Event(
        t, round(t * 25), person, "", "behaviour", type_, t, rule=rule, position=(1.0, 2.0)
    )


def test_behaviour_alarms_left_open_are_ended_at_the_restart(tmp_path: Path) -> None:
    """person_down without person_up, lone_worker without its end: each ended, marked restart,
    through the same closing events as the zone exits; ended alarms stay ended."""
    db = tmp_path / "events.sqlite"
    sink = SqliteSink(db, first_id=1)
    sink.write_events(
        [
            behaviour(1.0, 1, "person_down", "man_down"),
            behaviour(2.0, 2, "lone_worker", "two_person"),
            behaviour(3.0, 3, "person_down", "man_down"),
            behaviour(4.0, 3, "person_up", "man_down"),  # up again: closed
            Event(4.0, 100, 4, "panel", "energized", "enter", 4.0),
        ]
    )
    sink.close()
    resume = Resume.from_log(db)
    assert [(a.rule, a.type, a.person) for a in resume.alarms] == [
        ("man_down", "person_down", 1),
        ("two_person", "lone_worker", 2),
    ]
    closing = resume.closing_events(0.5, 0)
    assert [(e.kind, e.type, e.person, e.rule, e.restart) for e in closing] == [
        ("energized", "exit", 4, None, True),
        ("behaviour", "person_up", 1, "man_down", True),
        ("behaviour", "lone_worker_end", 2, "two_person", True),
    ]
    again = SqliteSink(db, first_id=resume.next_id)
    again.write_events(closing)
    again.close()
    after = Resume.from_log(db)
    assert after.alarms == () and after.open_zones == {}
    stored = query_events(db)[-2:]
    assert [(r["type"], r["rule"], r["restart"]) for r in stored] == [
        ("person_up", "man_down", True),
        ("lone_worker_end", "two_person", True),
    ]


def test_next_id_covers_reserved_ids_that_no_event_names(tmp_path: Path) -> None:
    db = tmp_path / "events.sqlite"
    sink = SqliteSink(db, first_id=1, id_block=100)  # reserves 1..100 before any id is given
    assert Resume.from_log(db).next_id == 101
    sink.close()
    sink = SqliteSink(db, first_id=Resume.from_log(db).next_id, id_block=100)
    assert Resume.from_log(db).next_id == 201
    sink.write_events([Event(1.0, 1, 5000, "z", "restricted", "enter", 1.0)])
    sink.close()
    assert Resume.from_log(db).next_id == 5001


def test_no_log_is_a_fresh_start_and_a_foreign_file_is_refused(tmp_path: Path) -> None:
    fresh = Resume.from_log(tmp_path / "none.sqlite")
    assert (fresh.next_id, fresh.open_zones, fresh.runs, fresh.crashed) == (1, {}, 0, False)
    assert fresh.closing_events(0.0, 0) == []
    junk = tmp_path / "junk.sqlite"
    junk.write_bytes(b"not a database at all" * 100)
    with pytest.raises(StereoposeError, match=r"junk\.sqlite: cannot resume"):
        Resume.from_log(junk)
    other = tmp_path / "other.sqlite"
    sqlite3.connect(other).execute("CREATE TABLE things (x)").connection.close()
    with pytest.raises(StereoposeError, match="not an event log"):
        Resume.from_log(other)


OLD_SCHEMA = """
CREATE TABLE runs (id INTEGER PRIMARY KEY, started REAL NOT NULL, site TEXT, source TEXT);
CREATE TABLE events (
    id INTEGER PRIMARY KEY, run INTEGER NOT NULL REFERENCES runs(id), t REAL NOT NULL,
    frame INTEGER NOT NULL, person INTEGER NOT NULL, zone TEXT NOT NULL, kind TEXT NOT NULL,
    type TEXT NOT NULL, onset_t REAL, joint TEXT, distance_m REAL, duration_s REAL, x REAL,
    y REAL, allowed INTEGER NOT NULL DEFAULT 0, lost INTEGER NOT NULL DEFAULT 0);
INSERT INTO runs VALUES (1, 1750000000.0, 'site', 'run');
INSERT INTO events(run, t, frame, person, zone, kind, type, onset_t)
    VALUES (1, 1.0, 25, 7, 'panel', 'energized', 'enter', 1.0);
"""


def test_a_log_of_the_earlier_schema_is_read_resumed_and_upgraded(tmp_path: Path) -> None:
    db = tmp_path / "events.sqlite"
    con = sqlite3.connect(db)
    con.executescript(OLD_SCHEMA)
    con.close()
    (row,) = query_events(db)  # read as it is, without being changed
    assert (row["person"], row["restart"], row["camera"]) == (7, 0, None)
    resume = Resume.from_log(db)
    assert resume.next_id == 8 and resume.open_zones == {"panel": (7,)}
    assert not resume.crashed  # an earlier version did not record clean ends: not known
    sink = SqliteSink(db, first_id=resume.next_id)
    sink.write_events(resume.closing_events(0.0, 0))
    sink.close()
    rows = query_events(db)
    assert [(r["person"], r["type"], r["restart"]) for r in rows] == [
        (7, "enter", 0),
        (7, "exit", 1),
    ]
    ended = sqlite3.connect(db).execute("SELECT ended FROM runs ORDER BY id").fetchall()
    assert ended[0] == (None,) and ended[1][0] is not None


def test_the_tracker_gives_ids_from_first_id(shared_data_dir: Path) -> None:
    from stereopose.calibration.formats import load_calibration
    from stereopose.detection.openpose import read_pose_dir
    from stereopose.reconstruction import Reconstructor

    rig = load_calibration(shared_data_dir / "calib.toml")
    frames = list(read_pose_dir(shared_data_dir / "pose", rig.names))[:30]
    rec = Reconstructor(rig)
    memory = make_memory(rig, Config(), first_id=1001)
    assert isinstance(memory, Tracker)
    ids = set()
    for f, people2d in frames:
        prior = memory.prior(f)
        ids |= set(memory.update(f, rec.reconstruct(f, people2d, prior)).ids.tolist())
    assert ids and min(ids) == 1001
    with pytest.raises(ValueError, match="first_id"):
        Tracker(rig, first_id=0)
