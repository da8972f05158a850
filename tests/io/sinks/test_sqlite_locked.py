"""The SQLite event log while another connection holds its write lock: the writer never
blocks, keeps the events, stores them once the lock is gone, and loses none."""

from __future__ import annotations

import sqlite3
import threading
from collections.abc import Callable
from pathlib import Path

from stereopose.io.records import event_record
from stereopose.io.sinks.events import query_events, read_events
from stereopose.io.sinks.eventwriter import LockWaits, SqliteSink
from stereopose.types import Event
from waiting import wait_until


def event(k: int) -> Event:
    return Event(
        t=k / 25,
        frame=k,
        person=1 + k % 2,
        zone="panel",
        kind="energized",
        type="enter",
        onset_t=k / 25,
    )


class Lock:
    """Another connection holding BEGIN IMMEDIATE on `db` from its own thread, from `hold()`
    until `release_when()` is true (checked every 10 ms)."""

    def __init__(self, db: Path, release_when: Callable[[], bool]) -> None:
        self.db, self.release_when = db, release_when
        self.held, self.released = threading.Event(), threading.Event()
        self._thread = threading.Thread(target=self._hold, daemon=True)

    def hold(self) -> None:
        self._thread.start()
        assert self.held.wait(20), "the other connection did not get the lock"

    def _hold(self) -> None:
        con = sqlite3.connect(self.db, isolation_level=None)
        con.execute("BEGIN IMMEDIATE")
        self.held.set()
        wait_until(self.release_when, "the condition to release the lock", timeout_s=30)
        con.execute("COMMIT")
        con.close()
        self.released.set()

    def join(self) -> None:
        self._thread.join(30)
        assert self.released.is_set()


def returns(call, *args) -> None:
    t = threading.Thread(target=call, args=args, daemon=True)
    t.start()
    t.join(20)
    assert not t.is_alive(), "the write blocked on the lock"


def test_a_locked_log_keeps_the_events_and_stores_them_later(tmp_path: Path) -> None:
    db = tmp_path / "e.sqlite"
    sink = SqliteSink(db, waits=LockWaits(busy_s=0.01, retry_s=0.0))
    sink.write_events([event(0)])
    release = threading.Event()
    lock = Lock(db, release.is_set)
    lock.hold()
    for k in range(1, 21):  # 20 frames while the other connection holds the lock
        returns(sink.write_events, [event(k)])
    assert len(sink.pending) == 20 and sink.committed == 1
    assert len(query_events(db)) == 1  # a reader still reads (WAL), the others wait
    release.set()
    lock.join()
    sink.write_events([event(21)])  # the next frame stores all that waited, in order
    assert not sink.pending and sink.committed == 22
    sink.close()
    assert sink.incomplete is None
    assert [r["frame"] for r in query_events(db)] == list(range(22))


def test_close_waits_a_bounded_time_for_the_lock(tmp_path: Path) -> None:
    db = tmp_path / "e.sqlite"
    sink = SqliteSink(db, waits=LockWaits(busy_s=0.01, retry_s=0.0, close_timeout_s=20.0))
    closing = threading.Event()
    lock = Lock(db, closing.is_set)
    lock.hold()
    sink.write_events([event(k) for k in range(5)])
    assert len(sink.pending) == 5
    closer = threading.Thread(target=sink.close, daemon=True)
    closer.start()
    wait_until(lambda: sink._closed, "close to start")
    closing.set()  # the lock goes while close retries
    closer.join(30)
    assert not closer.is_alive() and sink.incomplete is None and not sink.pending
    assert [r["frame"] for r in query_events(db)] == list(range(5))
    lock.join()


def test_a_lock_held_past_close_keeps_the_events_beside_the_log(tmp_path: Path) -> None:
    db = tmp_path / "e.sqlite"
    sink = SqliteSink(db, waits=LockWaits(busy_s=0.01, retry_s=0.0, close_timeout_s=0.2))
    done = threading.Event()
    lock = Lock(db, done.is_set)
    lock.hold()
    events = [event(k) for k in range(7)]
    sink.write_events(events[:3])
    sink.write_events(events[3:])
    assert sink.close() == [db]
    done.set()
    lock.join()
    kept = tmp_path / "e.sqlite.unstored.jsonl"
    assert sink.kept_in == kept and "7 event(s) not stored" in sink.incomplete
    assert str(kept) in sink.incomplete
    assert [event_record(e) for e in read_events(kept)] == [event_record(e) for e in events]
    assert query_events(db) == []
    # a second run's unstored events are appended, never written over
    sink = SqliteSink(db, waits=LockWaits(busy_s=0.01, close_timeout_s=0.2))
    lock = Lock(db, done.is_set)
    done.clear()
    lock.hold()
    sink.write_events([event(9)])
    sink.close()
    done.set()
    lock.join()
    assert [e.frame for e in read_events(kept)] == [*range(7), 9]


def test_a_full_buffer_drops_and_counts(tmp_path: Path) -> None:
    db = tmp_path / "e.sqlite"
    sink = SqliteSink(
        db, waits=LockWaits(busy_s=0.01, retry_s=0.0, buffer_size=4, close_timeout_s=20.0)
    )
    closing = threading.Event()
    lock = Lock(db, closing.is_set)
    lock.hold()
    sink.write_events([event(k) for k in range(3)])
    sink.write_events([event(k) for k in range(3, 6)])  # one fits, two are dropped
    assert len(sink.pending) == 4 and sink.dropped == 2
    closing.set()
    sink.close()
    lock.join()
    assert [r["frame"] for r in query_events(db)] == [0, 1, 2, 3]
    assert "2 dropped" in sink.incomplete
