"""The command line's exit codes when outputs fail: 2 before any work for an output that cannot
be created, 3 when the work is done but an output could not be written (the others complete)."""

from __future__ import annotations

import sqlite3
from pathlib import Path

import pytest

from stereopose.cli import main
from stereopose.io.sinks import read_events

SITE = """fps = 25.0
[[zones]]
name = "everywhere"
kind = "work_area"
polygon = [[-100.0, -100.0], [100.0, -100.0], [100.0, 100.0], [-100.0, 100.0]]
z = [0.0, 3.0]
"""


@pytest.fixture(scope="module")
def scene(tmp_path_factory) -> Path:
    """A simulated recording on disk (calib.toml, pose/) and a zone everyone is in."""
    d = tmp_path_factory.mktemp("scene")
    args = ["--frames", "15", "--cameras", "3", "--people", "2", "--difficulty", "easy"]
    assert main(["simulate", str(d), *args]) == 0
    (d / "site.toml").write_text(SITE)
    return d


def _reconstruct(scene: Path, out: str, *more: str) -> int:
    return main(
        [
            "reconstruct",
            "--calib",
            str(scene / "calib.toml"),
            "--pose",
            str(scene / "pose"),
            "--out",
            out,
            *more,
        ]
    )


@pytest.mark.skipif(not Path("/dev/full").exists(), reason="needs /dev/full (ENOSPC on write)")
def test_a_full_disk_under_one_output_is_exit_3_and_the_alarms_are_kept(
    scene: Path, tmp_path: Path, capsys
) -> None:
    db, events = tmp_path / "e.sqlite", tmp_path / "e.jsonl"
    rc = _reconstruct(
        scene,
        "/dev/full",
        "--site",
        str(scene / "site.toml"),
        "--events-db",
        str(db),
        "--events",
        str(events),
    )
    printed = capsys.readouterr()
    err, out = printed.err, printed.out
    assert rc == 3
    assert "finished, but 1 output could not be written" in err
    assert "/dev/full: No space left on device" in err and "Traceback" not in err + out
    assert "3D poses written to /dev/full" in out  # the run's table, then what failed
    assert f"wrote {events}" in out.replace("\n", "")
    got = read_events(events)
    assert got
    with sqlite3.connect(db) as con:
        assert con.execute("select count(*) from events").fetchone()[0] == len(got)


def test_an_output_that_cannot_be_created_is_exit_2_before_any_work(
    scene: Path, tmp_path: Path, capsys
) -> None:
    (tmp_path / "file").write_text("")
    for out, more in (
        (str(tmp_path / "file" / "p.jsonl"), ()),
        (str(tmp_path / "p.jsonl"), ("--tracks", str(tmp_path / "file" / "t.json"))),
        (str(tmp_path / "p.jsonl"), ("--trc", str(tmp_path / "file" / "trc"))),
    ):
        assert _reconstruct(scene, out, *more) == 2
        err = capsys.readouterr().err
        assert "is a file, not a folder" in err and "Traceback" not in err
        assert not (tmp_path / "p.jsonl").exists() or (tmp_path / "p.jsonl").read_text() == ""


def test_calibrate_refuses_an_unwritable_output_before_the_work(tmp_path: Path, capsys) -> None:
    (tmp_path / "file").write_text("")
    (tmp_path / "photos").mkdir()
    base = [
        "calibrate",
        "intrinsics",
        "--images",
        str(tmp_path / "photos"),
        "--board",
        "9x6",
        "--square",
        "0.08",
    ]
    for out, more in (
        (tmp_path / "file" / "c.toml", ()),
        (tmp_path / "c.toml", ("--report", str(tmp_path / "file" / "pictures"))),
        (tmp_path / "file" / "yaml", ()),
    ):
        assert main([*base, "--out", str(out), *more]) == 2
        err = capsys.readouterr().err
        assert "is a file, not a folder" in err and "cannot write the" in err
