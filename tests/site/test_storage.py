"""The storage maintainer: retention by age, a byte cap oldest first, old events pruned from a
real event log (also while another connection holds its lock), failures counted, a thread."""

from __future__ import annotations

import os
import sqlite3
from pathlib import Path

import pytest

from stereopose.errors import ConfigError
from stereopose.io.sinks.events import query_events
from stereopose.io.sinks.eventwriter import SqliteSink
from stereopose.site.storage import RetentionSettings, StorageMaintainer
from stereopose.types import Event
from waiting import wait_until

DAY = 86400.0
NOW = 1_750_000_000.0  # the maintainer's clock in these tests


def put(path: Path, age_days: float, size: int = 100) -> Path:
    """A real file of `size` bytes last written `age_days` before NOW."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(b"x" * size)
    os.utime(path, (NOW - age_days * DAY, NOW - age_days * DAY))
    return path


def names(folder: Path) -> set[str]:
    return {p.name for p in folder.iterdir()} if folder.is_dir() else set()


def maintainer(out: Path, **kw) -> StorageMaintainer:
    log = kw.pop("event_log", None)
    return StorageMaintainer(out, event_log=log, settings=RetentionSettings(**kw), now=lambda: NOW)


def test_files_past_their_retention_go_the_newest_segment_and_clips_being_written_stay(
    tmp_path: Path,
) -> None:
    poses, clips = tmp_path / "poses", tmp_path / "clips"
    put(poses / "20250101-000000.jsonl.gz", 10)
    put(poses / "20250102-000000.jsonl.gz", 9)
    put(poses / "20250103-000000.jsonl.gz", 8.5)  # the newest: being written, never deleted
    put(poses / "notes.txt", 100)  # not a segment: not ours
    put(clips / "20250101-000000_3_panel_cam1.mp4", 31)
    put(clips / "20250102-000000_3_panel_cam1.mp4", 29)
    put(clips / "20250103-000000_4_panel_cam1.part.mp4", 0.001)  # being written
    put(clips / "20241201-000000_4_panel_cam2.part.mp4", 40)  # a crashed writer's leftover
    os.symlink(poses / "notes.txt", poses / "20240101-000000.jsonl.gz")  # a link: not ours
    result = maintainer(tmp_path, retention_days=7, clip_retention_days=30).run_once()
    assert names(poses) == {"20250103-000000.jsonl.gz", "notes.txt", "20240101-000000.jsonl.gz"}
    assert names(clips) == {
        "20250102-000000_3_panel_cam1.mp4",
        "20250103-000000_4_panel_cam1.part.mp4",
    }
    assert result.deleted == {"segments": 2, "clips": 2, "events": 0}
    assert result.freed_bytes["segments"] == 200 and result.usage["segments"] == 100
    assert result.usage["clips"] == 200 and result.errors == 0


def test_above_the_cap_the_oldest_go_first(tmp_path: Path) -> None:
    put(tmp_path / "poses" / "20250101-000000.jsonl.gz", 3, 1000)
    put(tmp_path / "poses" / "20250102-000000.jsonl.gz", 1, 1000)
    put(tmp_path / "poses" / "20250103-000000.jsonl.gz", 0, 1000)  # being written
    put(tmp_path / "clips" / "a.mp4", 2, 1000)
    put(tmp_path / "clips" / "b.mp4", 0.5, 1000)
    m = maintainer(tmp_path, max_bytes=2500)
    result = m.run_once()
    assert names(tmp_path / "poses") == {"20250103-000000.jsonl.gz"}
    assert names(tmp_path / "clips") == {"b.mp4"}
    assert result.deleted["segments"] == 2 and result.deleted["clips"] == 1
    assert not result.over_cap and m.usage() == {"segments": 1000, "clips": 1000, "events": 0}


def test_the_file_being_written_stays_even_above_the_cap(tmp_path: Path, caplog) -> None:
    put(tmp_path / "poses" / "20250103-000000.jsonl.gz", 0, 5000)
    put(tmp_path / "clips" / "c.part.mp4", 0, 5000)
    result = maintainer(tmp_path, max_bytes=1000).run_once()
    assert names(tmp_path / "poses") and names(tmp_path / "clips")
    assert result.over_cap and "above max_bytes" in caplog.text


def event_log(path: Path, times: list[float], started: float) -> Path:
    sink = SqliteSink(path)
    # in and out in turn: the last one an exit, so that no enter is kept as open
    n = len(times)
    sink.write_events(
        [
            Event(
                t,
                int(t * 10),
                1,
                "panel",
                "energized",
                "exit" if (n - 1 - i) % 2 == 0 else "enter",
                t,
            )
            for i, t in enumerate(times)
        ]
    )
    sink.close()
    with sqlite3.connect(path) as db:  # the run started at `started` (Unix time)
        db.execute("UPDATE runs SET started = ?", (started,))
    return path


def test_old_events_are_pruned_in_small_batches(tmp_path: Path) -> None:
    # a run that started 30 days and 100 s before NOW: its events at t < 100 are 30 days old
    log = event_log(
        tmp_path / "events.sqlite", [float(t) for t in range(200)], NOW - 30 * DAY - 100
    )
    result = maintainer(tmp_path, event_log=log, event_retention_days=30, event_batch=7).run_once()
    assert result.deleted["events"] == 100 and not result.events_locked
    assert [e["t"] for e in query_events(log)] == [float(t) for t in range(100, 200)]
    assert result.usage["events"] > 0


def test_a_locked_event_log_is_tried_again_next_pass(tmp_path: Path) -> None:
    log = event_log(tmp_path / "events.sqlite", [1.0, 2.0], NOW - 400 * DAY)
    put(tmp_path / "clips" / "old.mp4", 100)
    m = maintainer(tmp_path, event_log=log, busy_s=0.01)
    holder = sqlite3.connect(log, isolation_level=None)
    holder.execute("BEGIN IMMEDIATE")  # another writer holds the write lock
    try:
        first = m.run_once()
    finally:
        holder.execute("ROLLBACK")
        holder.close()
    assert first.events_locked and first.deleted["events"] == 0 and first.errors == 0
    assert first.deleted["clips"] == 1  # the rest of the pass went on
    assert len(query_events(log)) == 2
    second = m.run_once()
    assert second.deleted["events"] == 2 and query_events(log) == []
    assert m.health()["events_locked"] == 1 and m.health()["deleted"]["events"] == 2


def test_a_damaged_event_log_is_an_error_counted_not_a_stop(tmp_path: Path) -> None:
    log = tmp_path / "events.sqlite"
    log.write_bytes(b"not a database" * 100)
    put(tmp_path / "clips" / "old.mp4", 100)
    m = maintainer(tmp_path, event_log=log)
    result = m.run_once()
    assert result.errors == 1 and "events.sqlite" in m.health()["last_error"]
    assert result.deleted["clips"] == 1


def test_files_that_cannot_be_deleted_are_counted_and_the_pass_goes_on(
    tmp_path: Path, monkeypatch, caplog
) -> None:
    stuck = put(tmp_path / "clips" / "stuck.mp4", 100)
    gone = put(tmp_path / "clips" / "gone.mp4", 100)
    other = put(tmp_path / "clips" / "other.mp4", 100)
    unlink = Path.unlink

    def failing_unlink(self: Path, missing_ok: bool = False) -> None:
        if self == stuck:
            raise PermissionError(13, "Permission denied", str(self))
        if self == gone:  # removed by someone else between the listing and the delete
            unlink(self)
            raise FileNotFoundError(2, "No such file or directory", str(self))
        unlink(self, missing_ok)

    monkeypatch.setattr(Path, "unlink", failing_unlink)
    m = maintainer(tmp_path)
    result = m.run_once()
    assert names(tmp_path / "clips") == {"stuck.mp4"} and not other.exists()
    assert result.errors == 2 and result.deleted["clips"] == 1
    assert m.health()["errors"] == 2 and m.health()["last_error"]
    assert "stuck.mp4: cannot delete: Permission denied" in caplog.text
    assert "gone.mp4: gone before it could be deleted" in caplog.text


def test_the_thread_makes_passes_until_stopped(tmp_path: Path) -> None:
    m = maintainer(tmp_path, interval_s=0.01)
    m.start()
    try:
        wait_until(lambda: m.passes >= 1, "a first pass")
        old = put(tmp_path / "clips" / "old.mp4", 100)
        wait_until(lambda: not old.exists(), "a pass that deletes the old clip")
    finally:
        assert m.stop()
    assert m.health()["deleted"]["clips"] == 1 and m.health()["errors"] == 0


@pytest.mark.parametrize(
    ("key", "value"),
    [
        ("retention_days", 0),
        ("clip_retention_days", float("inf")),
        ("max_bytes", -1),
        ("max_bytes", 1.5),
        ("interval_s", 0),
        ("event_batch", 0),
        ("event_retention_days", True),
    ],
)
def test_settings_name_their_key(key: str, value: object) -> None:
    with pytest.raises(ConfigError, match=rf"storage\.{key}: expected"):
        RetentionSettings(**{key: value})
