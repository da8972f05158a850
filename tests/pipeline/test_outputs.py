"""Every sink opened by open_outputs writes what it should, also when the run fails."""

from __future__ import annotations

import dataclasses
import json
import sqlite3
import threading
from pathlib import Path

import numpy as np
import pytest
from frame_sources import SceneSource

from stereopose.config import Config, OutputConfig
from stereopose.errors import OutputError, StereoposeError
from stereopose.fence import FenceMonitor
from stereopose.io.exports import read_trc
from stereopose.io.records import event_record
from stereopose.io.results import read_poses
from stereopose.io.sinks import PosesSink, read_events
from stereopose.io.summary import RunSummary
from stereopose.pipeline.loop import FrameLoop
from stereopose.pipeline.outputs import Outputs, open_outputs
from stereopose.pipeline.reconstruct import save_inputs
from stereopose.pipeline.stage3d import Stage3D
from stereopose.pipeline.step_rules import step_chain
from stereopose.sim.events import make_zones

OLD_SUMMARY_KEYS = {
    "config",
    "cameras",
    "live",
    "fps_input",
    "frames",
    "wall_s",
    "fps",
    "seconds_per_stage",
    "fps_per_stage",
    "people_per_frame",
    "people",
    "events",
    "reprojection_median_px",
    "per_camera",
    "sources",
    "interrupted",
    "outputs",
}


def _run(scene, out: Path, *, fail_at=None, error=RuntimeError, two_way=False, report=True):
    cfg = dataclasses.replace(Config(), fps=scene.fps)
    site = make_zones(scene, np.random.default_rng(4))
    outputs = Outputs.run_folder(
        out, OutputConfig(two_way=two_way, report=report, overlays=False), site
    )
    stage = Stage3D(scene.rig, cfg, record=two_way)
    summary = RunSummary(scene.rig.names, SceneSource.stages, "robust", stage.tracking)
    got: list = []
    out.mkdir(parents=True, exist_ok=True)
    save_inputs(out, scene.rig, site)
    sinks = open_outputs(
        outputs,
        rig=scene.rig,
        config=cfg,
        summary=summary,
        stage=stage,
        site=site,
        source="sim",
        on_events=got.extend,
    )
    fences = FenceMonitor(site, cfg.fps)
    source = SceneSource(scene, fail_at, error)
    loop = FrameLoop(source, stage, sinks, summary, rules=step_chain(fences))
    return loop, sinks, got, source


def test_every_sink_writes_what_it_should(scene, tmp_path: Path) -> None:
    loop, sinks, got, source = _run(scene, tmp_path)
    summary = loop.run()
    F = len(scene.detections)
    poses = list(read_poses(tmp_path / "poses3d.jsonl"))
    assert [f for f, _, _ in poses] == list(range(F))
    ids = {p["id"] for _, _, people in poses for p in people}
    assert len(ids) >= 2
    # events: the same in JSON lines, SQLite and the callback, counted in the summary
    events = read_events(tmp_path / "events.jsonl")
    assert [event_record(e) for e in got] == [event_record(e) for e in events]
    assert sum(summary.events.values()) == len(events) > 0
    with sqlite3.connect(tmp_path / "events.sqlite") as db:
        assert db.execute("select count(*) from events").fetchone()[0] == len(events)
    # CSV: one row per joint of the poses file; TRC: each person's frames, first to last
    rows = (tmp_path / "joints.csv").read_text().splitlines()
    assert len(rows) - 1 == sum(
        j is not None for _, _, pp in poses for p in pp for j in p["joints"]
    )
    for i in ids:
        seen = [f for f, _, pp in poses if i in {p["id"] for p in pp}]
        frames = read_trc(tmp_path / "trc" / f"person_{i}.trc")[0]
        assert frames.tolist() == list(range(seen[0], seen[-1] + 1))
    assert {t["id"] for t in json.loads((tmp_path / "tracks.json").read_text())} == ids
    # the summary: every key it had, the new ones, and every file in the outputs
    s = json.loads((tmp_path / "summary.json").read_text())
    assert set(s) >= OLD_SUMMARY_KEYS and s["frames"] == F and not s["interrupted"]
    assert s["load_s_3d"] == summary.load_s_3d >= 0 and s["error"] is None
    assert set(s["per_camera"]) == set(scene.rig.names)
    assert all(c["frames"] == F and c["joints_compared"] > 0 for c in s["per_camera"].values())
    assert s["reprojection_median_px"] < 10 and s["people_histogram"]
    assert set(s["seconds_per_stage"]) == {"read", "3d", "fences", "write"}
    names = {Path(p).name for p in summary.outputs}
    assert {
        "poses3d.jsonl",
        "events.jsonl",
        "events.sqlite",
        "joints.csv",
        "tracks.json",
        "summary.json",
        "report.html",
    } <= names
    assert {f"person_{i}.trc" for i in ids} <= names
    assert "3D view" in (tmp_path / "report.html").read_text()
    assert source.finished and all(sink.close() == [] for sink in sinks)  # closed once


@pytest.mark.parametrize("error", [RuntimeError, KeyboardInterrupt])
def test_a_failing_run_closes_every_sink_and_keeps_files_readable(scene, tmp_path, error):
    loop, sinks, _, _ = _run(scene, tmp_path, fail_at=7, error=error)
    if error is KeyboardInterrupt:
        assert loop.run().interrupted  # Ctrl-C: a run cut short, not an error
    else:
        with pytest.raises(RuntimeError, match="failed at frame 7"):
            loop.run()
    assert [f for f, _, _ in read_poses(tmp_path / "poses3d.jsonl")] == list(range(7))
    read_events(tmp_path / "events.jsonl")
    with sqlite3.connect(tmp_path / "events.sqlite") as db:
        assert db.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
    for trc in (tmp_path / "trc").iterdir():
        assert read_trc(trc)[0][-1] <= 6
    assert (tmp_path / "joints.csv").read_text().splitlines()[0].startswith("frame,t")
    s = json.loads((tmp_path / "summary.json").read_text())
    assert s["frames"] == 7
    if error is KeyboardInterrupt:
        assert s["interrupted"] and s["error"] is None and (tmp_path / "report.html").is_file()
    else:
        assert "failed at frame 7" in s["error"] and not (tmp_path / "report.html").exists()
    assert all(sink.close() == [] for sink in sinks)


def test_two_way_exports_are_smoothed_at_close(scene, tmp_path: Path) -> None:
    online, two = tmp_path / "online", tmp_path / "two"
    for out, flag in ((online, False), (two, True)):
        loop, *_ = _run(scene, out, two_way=flag, report=False)
        summary = loop.run()
        assert summary.two_way_frames == (len(scene.detections) if flag else 0)
    assert (online / "poses3d.jsonl").read_text() == (two / "poses3d.jsonl").read_text()
    a = (online / "joints.csv").read_text().splitlines()
    b = (two / "joints.csv").read_text().splitlines()
    assert [r.split(",")[:4] for r in a] == [r.split(",")[:4] for r in b] and a != b
    assert json.loads((two / "summary.json").read_text())["two_way_frames"] == 30


def test_outputs_of_a_run_folder_and_of_keywords(tmp_path: Path) -> None:
    o = Outputs.run_folder(tmp_path, OutputConfig(csv=False, overlays=False), site=None)
    assert o.poses == tmp_path / "poses3d.jsonl" and o.csv is None and o.events is None
    assert o.overlays_dir is None and o.report_dir == tmp_path
    k = Outputs.from_keywords("p.jsonl", trc_dir="trc", events_path="e.jsonl", webhook=None)
    assert (k.poses, k.trc_dir, k.events, k.webhook) == (
        Path("p.jsonl"),
        Path("trc"),
        Path("e.jsonl"),
        None,
    )
    with pytest.raises(TypeError, match=r"unknown output keyword.*trc_path"):
        Outputs.from_keywords("p.jsonl", trc_path="trc")


def test_an_output_that_cannot_be_opened_closes_the_others(scene, tmp_path, monkeypatch):
    closed = []
    monkeypatch.setattr(PosesSink, "close", lambda self: closed.append(self) or [])
    (tmp_path / "file").write_text("")
    outputs = Outputs(poses=tmp_path / "p.jsonl", csv=tmp_path / "file" / "j.csv")
    cfg = Config()
    stage = Stage3D(scene.rig, cfg)
    with pytest.raises(StereoposeError, match="cannot write CSV"):
        open_outputs(
            outputs, rig=scene.rig, config=cfg, stage=stage, summary=RunSummary(scene.rig.names)
        )
    assert len(closed) == 1


@pytest.mark.parametrize("memory", ["recent", "none"])
def test_zone_events_and_two_way_need_the_trackers_ids(memory: str) -> None:
    from stereopose.config import Config, with_overrides
    from stereopose.errors import StereoposeError
    from stereopose.fence import Site
    from stereopose.pipeline.outputs import Outputs, check_outputs

    cfg = with_overrides(Config(), tracking={"memory": memory})
    with pytest.raises(StereoposeError, match=r'zone events need tracking.*memory = "tracker"'):
        check_outputs(cfg, Site(()), Outputs(poses=None))
    with pytest.raises(StereoposeError, match="two-way smoothing needs tracking"):
        check_outputs(cfg, None, Outputs(poses=None, two_way=True))
    check_outputs(Config(), Site(()), Outputs(poses=None, two_way=True))  # the tracker: fine


def _loop(scene, out: Path, outputs: Outputs):
    """A frame loop over the scene with its zones, writing `outputs`; (loop, summary)."""
    cfg = dataclasses.replace(Config(), fps=scene.fps)
    site = make_zones(scene, np.random.default_rng(4))
    stage = Stage3D(scene.rig, cfg)
    summary = RunSummary(scene.rig.names, SceneSource.stages, "robust", stage.tracking)
    sinks = open_outputs(
        outputs, rig=scene.rig, config=cfg, summary=summary, stage=stage, site=site, source="sim"
    )
    return FrameLoop(
        SceneSource(scene), stage, sinks, summary, rules=step_chain(FenceMonitor(site, cfg.fps))
    )


@pytest.mark.skipif(not Path("/dev/full").exists(), reason="needs /dev/full (ENOSPC on write)")
def test_a_full_disk_stops_that_output_alone(scene, tmp_path: Path, caplog) -> None:
    outputs = Outputs(
        poses=Path("/dev/full"),
        events=tmp_path / "events.jsonl",
        events_db=tmp_path / "events.sqlite",
        csv=tmp_path / "joints.csv",
        summary=tmp_path / "summary.json",
    )
    summary = _loop(scene, tmp_path, outputs).run()
    F = len(scene.detections)
    assert summary.frames == F  # every frame processed
    assert summary.failed_outputs == {"/dev/full": "No space left on device"}
    assert Path("/dev/full") not in summary.outputs
    # one error for the output, not one per frame
    assert sum("/dev/full" in r.getMessage() for r in caplog.records if r.levelname == "ERROR") == 1
    # the alarm path and the other files are complete
    events = read_events(tmp_path / "events.jsonl")
    assert events
    with sqlite3.connect(tmp_path / "events.sqlite") as db:
        assert db.execute("select count(*) from events").fetchone()[0] == len(events)
    frames = {int(r.split(",")[0]) for r in (tmp_path / "joints.csv").read_text().splitlines()[1:]}
    assert max(frames) == F - 1
    s = json.loads((tmp_path / "summary.json").read_text())
    assert s["failed_outputs"] == {"/dev/full": "No space left on device"} and s["frames"] == F


def test_an_output_folder_that_turns_into_a_file_stops_that_output(scene, tmp_path: Path) -> None:
    trc = tmp_path / "trc"
    outputs = Outputs(poses=tmp_path / "poses.jsonl", trc_dir=trc)
    loop = _loop(scene, tmp_path, outputs)
    trc.rmdir()
    trc.write_text("")  # the folder is gone, a file in its place: each person's file fails
    summary = loop.run()
    assert summary.frames == len(scene.detections)
    assert list(summary.failed_outputs) == [str(trc)]
    assert "cannot write TRC" in summary.failed_outputs[str(trc)]
    assert len((tmp_path / "poses.jsonl").read_text().splitlines()) == len(scene.detections)


@pytest.mark.parametrize(
    ("field", "name", "message"),
    [
        ("tracks", "file/tracks.json", "cannot write trajectories: .*file is a file, not a folder"),
        ("trc_dir", "file/trc", "cannot write TRC files: .*file is a file, not a folder"),
        ("summary", "folder", "cannot write the run summary: a folder is in its place"),
        (
            "events_db",
            "file/e.sqlite",
            "cannot write the event database: .*file is a file, not a folder",
        ),
        ("report_dir", "file", "cannot write the report: .*file is a file, not a folder"),
    ],
)
def test_an_output_that_cannot_be_written_is_refused_before_any_frame(
    scene, tmp_path: Path, field: str, name: str, message: str
) -> None:
    (tmp_path / "file").write_text("")
    (tmp_path / "folder").mkdir()
    outputs = dataclasses.replace(Outputs(poses=tmp_path / "p.jsonl"), **{field: tmp_path / name})
    with pytest.raises(OutputError, match=message):
        _loop(scene, tmp_path, outputs)
    assert (tmp_path / "p.jsonl").read_text() == ""  # opened, closed again, nothing written


class _Writer:
    """Another connection holding the event log's write lock from its own thread, from
    `hold()` until `release()`."""

    def __init__(self, db: Path) -> None:
        self.db = db
        self.held, self.go, self.done = threading.Event(), threading.Event(), threading.Event()

    def hold(self) -> None:
        threading.Thread(target=self._run, daemon=True).start()
        assert self.held.wait(20), "the other connection did not get the lock"

    def _run(self) -> None:
        con = sqlite3.connect(self.db, isolation_level=None)
        con.execute("BEGIN IMMEDIATE")
        self.held.set()
        self.go.wait(30)
        con.execute("COMMIT")
        con.close()
        self.done.set()

    def release(self) -> None:
        self.go.set()
        assert self.done.wait(20)


def test_a_locked_event_log_neither_stops_the_run_nor_loses_events(scene, tmp_path: Path):
    db = tmp_path / "events.sqlite"
    outputs = Outputs(events=tmp_path / "events.jsonl", events_db=db)
    loop = _loop(scene, tmp_path, outputs)
    F = len(scene.detections)
    writer = _Writer(db)
    stored_under_lock: list[int] = []

    def on_step(done: int, total, fps) -> None:
        if done == 5:
            writer.hold()  # from frame 5 on, another process writes to the log
        if done == F:  # every frame went through under the lock; then it goes
            with sqlite3.connect(db) as con:  # a reader is not held up either (WAL)
                stored_under_lock.append(con.execute("select count(*) from events").fetchone()[0])
            writer.release()

    loop.on_step = on_step
    summary = loop.run()
    assert summary.frames == F and summary.failed_outputs == {}
    events = read_events(tmp_path / "events.jsonl")
    late = [e for e in events if e.frame >= 5]
    assert late, "the scene should raise events after frame 5"
    assert stored_under_lock == [len(events) - len(late)]
    with sqlite3.connect(db) as con:
        rows = con.execute("select frame, person, zone, type from events order by id").fetchall()
    assert rows == [(e.frame, e.person, e.zone, e.type) for e in events]
