"""Incident ids from a real event log's `incidents` mark: strictly increasing across
instances (a restart) even when none was stored, a block reserved ahead, and a log locked by
another writer never raising in the frame loop's top-up (the ids already reserved go on)."""

from __future__ import annotations

import sqlite3

from stereopose.io.sinks.eventdb import read_mark
from stereopose.io.sinks.eventwriter import SqliteSink
from stereopose.io.sinks.incidents import IncidentIds


def test_ids_increase_across_restarts_and_a_locked_log_is_waited_out(tmp_path) -> None:
    path = tmp_path / "events.sqlite"
    SqliteSink(path, "site", "test").close()
    ids = IncidentIds(path, block=4)
    first = [ids() for _ in range(3)]
    assert first == [1, 2, 3]
    ids.close()  # three taken, one reserved and never given: skipped, never reused
    again = IncidentIds(path, block=4)
    assert [again(), again(), again()] == [5, 6, 7]  # one of the block left
    other = sqlite3.connect(path, isolation_level=None)
    other.execute("BEGIN IMMEDIATE")  # another writer holds the log
    try:
        again.top_up(busy_s=0.01)  # asks for the next block, cannot, goes on
        assert again.failed == 1
        assert again() == 8  # from the block already reserved
    finally:
        other.execute("ROLLBACK")
        other.close()
    again.top_up()
    assert again.left() == 4 and again() == 9
    db = sqlite3.connect(path)
    try:
        assert read_mark(db, "incidents") == 13
    finally:
        db.close()
    again.close()
