"""The read-side commands on damaged or hostile input: `report` and `events` never crash."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from stereopose.cli import main
from stereopose.config import Config
from stereopose.io.sinks.eventwriter import SqliteSink
from stereopose.types import Event

SITE = """
fps = 25.0
[[zones]]
name = "hall"
kind = "work_area"
polygon = [[-20.0, -20.0], [20.0, -20.0], [20.0, 20.0], [-20.0, 20.0]]
z = [0.0, 3.0]
"""


@pytest.fixture(scope="module")
def run_folder(tmp_path_factory) -> Path:
    """A run folder of a small simulated reconstruction, its report written."""
    from stereopose.fence import load_site
    from stereopose.pipeline import Outputs, reconstruct_files
    from stereopose.pipeline.reconstruct import write_reconstruction_report
    from stereopose.sim import simulate
    from stereopose.sim.io import write_scene

    root = tmp_path_factory.mktemp("read_side")
    scene = simulate(num_cameras=3, num_people=2, num_frames=20, seed=3, difficulty="easy")
    write_scene(scene, root / "scene")
    (root / "site.toml").write_text(SITE)
    site = load_site(root / "site.toml")
    run = root / "run"
    run.mkdir()
    outputs = Outputs.from_keywords(run / "poses3d.jsonl", events_path=run / "events.jsonl")
    summary = reconstruct_files(
        root / "scene" / "calib.toml",
        root / "scene" / "pose",
        None,
        Config(),
        outputs=outputs,
        site=site,
    )
    write_reconstruction_report(
        run,
        summary,
        root / "scene" / "calib.toml",
        site,
        run / "poses3d.jsonl",
        run / "events.jsonl",
    )
    (run / "config.toml").write_text("fps = 25.0\n")
    return run


@pytest.fixture
def run_copy(run_folder: Path, tmp_path: Path) -> Path:
    run = tmp_path / "run"
    shutil.copytree(run_folder, run)
    (run / "report.html").unlink()
    return run


def report(run: Path, capsys, caplog) -> tuple[int, str]:
    """Exit code and everything printed or logged (pytest captures the log apart)."""
    caplog.clear()
    rc = main(["report", str(run)])
    captured = capsys.readouterr()
    text = captured.out + captured.err + caplog.text
    assert "Traceback" not in text
    return rc, " ".join(text.split())


def test_a_damaged_poses_line_is_skipped_and_counted(run_copy: Path, capsys, caplog) -> None:
    poses = run_copy / "poses3d.jsonl"
    lines = poses.read_bytes().splitlines(keepends=True)
    lines[3] = b'{"frame": 3, "people": [{"id": 1e999, "joints": []}]}\n'
    lines[5] = b"\xff" + b"[" * 100_000 + b"\n"
    poses.write_bytes(b"".join(lines))
    rc, text = report(run_copy, capsys, caplog)
    assert rc == 0
    assert "2 damaged line(s) skipped (first: line 4)" in text and "poses3d.jsonl" in text
    page = (run_copy / "report.html").read_text()
    assert "2 damaged line(s) of poses3d.jsonl skipped" in page and "3D view" in page


@pytest.mark.parametrize(
    ("content", "problem"),
    [
        (b"{not json", "unreadable run summary"),
        (b"[]", "expected a JSON object, got list"),
        (b"\xff\xfe", "not UTF-8"),
        (b"[" * 100_000, "nested too deeply"),
        (b'{"fps": ' + b"9" * 5000 + b"}", "unreadable run summary"),
        (b'{"fps": "fast"}', "fps: expected a number or null, got 'fast'"),
        (b'{"fps": ' + b"9" * 400 + b"}", "fps: expected a number"),
        (b'{"fps_per_stage": [1]}', "fps_per_stage: expected an object"),
        (b'{"cameras": "cam"}', "cameras: expected a list"),
        (b'{"people": [3]}', "people[0]: expected an object with an id"),
        (b'{"people": [{"id": 1, "path_m": "far"}]}', "people[0].path_m"),
        (b'{"per_camera": {"c1": {"reprojection_mean_px": []}}}', "per_camera.c1"),
        (b'{"sources": {"c1": 5}}', "sources.c1: expected an object"),
    ],
)
def test_a_damaged_summary_is_an_error_naming_it(
    run_copy: Path, capsys, caplog, content: bytes, problem: str
) -> None:
    (run_copy / "summary.json").write_bytes(content)
    rc, text = report(run_copy, capsys, caplog)
    assert rc == 2 and "summary.json" in text and problem in text
    assert not (run_copy / "report.html").exists()


@pytest.mark.parametrize(
    ("content", "problem"),
    [(b"fps = [\n", "invalid TOML"), (b"a = 1\n\xff\n", "not UTF-8"), (b"x = " + b"[" * 5000, "")],
)
def test_a_damaged_config_is_an_error_naming_it(
    run_copy: Path, capsys, caplog, content: bytes, problem: str
) -> None:
    (run_copy / "config.toml").write_bytes(content)
    rc, text = report(run_copy, capsys, caplog)
    assert rc == 2 and "config.toml" in text and problem in text


def test_damaged_events_give_a_report_without_events(run_copy: Path, capsys, caplog) -> None:
    (run_copy / "events.jsonl").write_text('{"t": ' + "9" * 400 + ', "frame": 1}\n')
    rc, text = report(run_copy, capsys, caplog)
    assert rc == 0 and "events.jsonl:1: malformed event line" in text


def test_a_summary_that_is_not_a_file(run_copy: Path, capsys, caplog) -> None:
    (run_copy / "summary.json").unlink()
    (run_copy / "summary.json").mkdir()
    rc, text = report(run_copy, capsys, caplog)
    assert rc == 2 and "summary.json" in text and "not a regular file" in text


@pytest.fixture
def event_db(tmp_path: Path) -> Path:
    db = tmp_path / "e.sqlite"
    sink = SqliteSink(db)
    sink.write_events(
        [
            Event(
                t=0.5, frame=12, person=3, zone="[/]", kind="work_area", type="enter", onset_t=0.4
            ),
            Event(
                t=0.9,
                frame=22,
                person=4,
                zone="[bold]x",
                kind="restricted",
                type="exit",
                onset_t=0.9,
            ),
        ]
    )
    sink.close()
    return db


def events(db: Path, capsys, *extra: str) -> tuple[int, str]:
    rc = main(["events", str(db), *extra])
    captured = capsys.readouterr()
    assert "Traceback" not in captured.out + captured.err
    return rc, captured.out + captured.err


@pytest.mark.parametrize("person", ["99999999999999999999", str(-(2**64)), "-1", "7"])
def test_events_of_a_person_beyond_any_id_are_none(event_db: Path, capsys, person: str) -> None:
    rc, text = events(event_db, capsys, "--person", person)
    assert rc == 0 and "0 event(s)" in text
    rc, text = events(event_db, capsys, "--person", person, "--csv")
    assert rc == 0 and text.splitlines() == [text.splitlines()[0]]  # the header alone


def test_zone_names_are_shown_as_they_are(event_db: Path, capsys) -> None:
    rc, text = events(event_db, capsys)  # a table: the names are not read as markup
    assert rc == 0 and "2 event(s)" in text
    rc, text = events(event_db, capsys, "--csv")
    assert rc == 0 and ",[/]," in text and ",[bold]x," in text
    rc, text = events(event_db, capsys, "--zone", "[/]")
    assert rc == 0 and "1 event(s)" in text


@pytest.mark.parametrize(
    ("extra", "problem"),
    [(("--since", "nan"), "--since must be a time"), (("--zone", "\udcff"), "not valid text")],
)
def test_bad_filters_are_errors(event_db: Path, capsys, extra: tuple, problem: str) -> None:
    rc, text = events(event_db, capsys, *extra)
    assert rc == 2 and problem in text


def test_events_summary_matches_the_log(event_db: Path, capsys) -> None:
    rc, text = events(event_db, capsys, "--csv", "--person", "3")
    rows = text.splitlines()
    assert rc == 0 and len(rows) == 2 and json.dumps("[/]")[1:-1] in rows[1]


def test_a_run_cut_mid_line_reports_the_frames_before(run_copy: Path, capsys, caplog) -> None:
    poses = run_copy / "poses3d.jsonl"
    text = poses.read_text()
    poses.write_text(text[: len(text) - len(text.splitlines()[-1]) // 2 - 1])  # killed mid-line
    rc, printed = report(run_copy, capsys, caplog)
    assert rc == 0 and "1 damaged line(s) skipped (first: line 20)" in printed


def test_a_reader_that_stops_early_ends_the_listing_quietly(tmp_path: Path) -> None:
    """`stereopose events LOG --csv | head -1`: the closed pipe is no error and no traceback."""
    import subprocess
    import sys

    db = tmp_path / "many.sqlite"
    sink = SqliteSink(db)
    sink.write_events(
        [
            Event(t=i / 25, frame=i, person=1, zone="z", kind="work_area", type="enter", onset_t=0)
            for i in range(20000)
        ]
    )
    sink.close()
    cmd = [sys.executable, "-m", "stereopose.cli", "events", str(db), "--csv"]
    with subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE) as p:
        first = p.stdout.readline()
        p.stdout.close()  # as `head -1` does
        err = p.stderr.read().decode()
        rc = p.wait(timeout=60)
    assert first.startswith(b"run,")
    assert rc == 0, err
    assert "Traceback" not in err and "BrokenPipe" not in err
