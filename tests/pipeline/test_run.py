"""`stereopose run` end to end on the real videos: outputs, consistency, Ctrl-C, bad input."""

from __future__ import annotations

import json
import os
import signal
import sqlite3
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from stereopose.cli import main
from stereopose.io.pose2sim_data import pose2sim_demo_dir
from stereopose.io.results import read_poses
from stereopose.io.sinks.events import read_events
from stereopose.pipeline.demo import write_demo_config
from waiting import listening, wait_until

pytestmark = [pytest.mark.realdata, pytest.mark.slow]


def test_demo_writes_every_output(real_demo_dir: Path) -> None:
    names = (
        "poses3d.jsonl",
        "events.jsonl",
        "events.sqlite",
        "report.html",
        "summary.json",
        "joints.csv",
        "tracks.json",
        "calib.toml",
        "site.toml",
        "config.toml",
    )
    for name in names:
        assert (real_demo_dir / name).is_file(), name
    for cam in ("cam01", "cam02", "cam03", "cam04"):
        video = cv2.VideoCapture(str(real_demo_dir / "overlays" / f"{cam}.mp4"))
        assert video.isOpened() and int(video.get(cv2.CAP_PROP_FRAME_COUNT)) == 100
        ok, frame = video.read()
        assert ok and frame.shape == (960, 544, 3)
    summary = json.loads((real_demo_dir / "summary.json").read_text())
    assert summary["frames"] == 100 and not summary["interrupted"] and summary["error"] is None
    assert summary["load_s_3d"] >= 0 and summary["fps_3d"] > 0
    assert set(summary["fps_per_stage"]) == {
        "decode",
        "detect",
        "3d",
        "fences",
        "write",
        "overlays",
    }
    for cam, stats in summary["per_camera"].items():
        assert stats["frames"] == 100 and stats["reprojection_median_px"] < 30, cam
    assert summary["reprojection_median_px"] < 15


def test_two_main_people_keep_one_id_each(real_demo_dir: Path) -> None:
    frames = {
        f: {p["id"]: p for p in people}
        for f, _, people in read_poses(real_demo_dir / "poses3d.jsonl")
    }
    assert sorted(frames) == list(range(100))
    # the two main people stand within 2 m of the treadmill's corner (the world origin)
    near = {
        pid
        for people in frames.values()
        for pid, p in people.items()
        if p["position"] is not None and abs(p["position"][0]) < 2 and abs(p["position"][1]) < 2
    }
    assert len(near) == 2, f"ids near the treadmill: {sorted(near)}"
    for pid in near:
        seen = [f for f, people in frames.items() if pid in people]
        assert seen[0] <= 3 and seen[-1] == 99 and len(seen) >= 97, (pid, seen[0], len(seen))


def test_events_belong_to_people_in_the_poses(real_demo_dir: Path) -> None:
    ids = {p["id"] for _, _, people in read_poses(real_demo_dir / "poses3d.jsonl") for p in people}
    events = read_events(real_demo_dir / "events.jsonl")
    assert events and {e.person for e in events if e.person >= 0} <= ids  # -1: a ticket's own
    kinds = {(e.zone, e.type) for e in events}
    assert ("overhead_busbar", "enter") in kinds and ("work_area", "enter") in kinds
    entered_work_area = {e.person for e in events if e.zone == "work_area" and e.type == "enter"}
    assert len(entered_work_area) == 2
    with sqlite3.connect(real_demo_dir / "events.sqlite") as db:
        (n,) = db.execute("select count(*) from events").fetchone()
    assert n == len(events)
    report = (real_demo_dir / "report.html").read_text()
    for pid in ids:
        assert f"id {pid}" in report
    assert "overhead_busbar" in report and "cdn" not in report.lower().split("<body>")[0][-2000:]


def test_the_demo_follows_its_ticket_and_reports_it(real_demo_dir: Path) -> None:
    """`make demo` runs with the demo's operation ticket: the walker does both steps in order
    from their position, the man beside him supervising; ticket.html reports it."""
    events = [e for e in read_events(real_demo_dir / "events.jsonl") if e.ticket == "OT-DEMO"]
    done = [e.step for e in events if e.type == "step_done"]
    assert done == ["open isolator QS1", "test busbar dead"]
    (end,) = [e for e in events if e.type == "ticket_completed"]
    assert end.result["done_in_order"] == done and end.result["deviations"] == 0
    page = (real_demo_dir / "ticket.html").read_text()
    assert "OT-DEMO" in page and all(name in page for name in done)
    assert 'id="replay"' in page and "2 of 2 steps done, 2 in order" in page


def _config(tmp_path: Path, cameras=("cam01", "cam02"), extra: str = "", sources=None) -> Path:
    """A run of the demo's cameras; ``extra`` is appended (tables)."""
    demo = pose2sim_demo_dir() / "Demo_MultiPerson"
    lines = [
        f'calibration = "{demo / "calibration" / "Calib.qca.txt"}"',
        f'output = "{tmp_path / "out"}"',
        "",
    ]
    for cam in cameras:
        src = (sources or {}).get(cam, demo / "videos" / f"{cam}.mp4")
        lines += ["[[cameras]]", f'name = "{cam}"', f'source = "{src}"', ""]
    path = tmp_path / "run.toml"
    path.write_text("\n".join(lines) + extra)
    return path


def test_sigint_during_a_run_leaves_valid_outputs(tmp_path: Path) -> None:
    cfg = _config(tmp_path, extra="\n[outputs]\noverlay_scale = 0.25\n")
    site = tmp_path / "site.toml"
    site.write_text((Path(write_demo_config(tmp_path / "d").parent) / "demo_site.toml").read_text())
    cfg.write_text(f'site = "{site}"\n' + cfg.read_text())
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    proc = subprocess.Popen(
        [sys.executable, "-m", "stereopose.cli", "run", str(cfg)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        env=env,
        text=True,
    )
    poses = tmp_path / "out" / "poses3d.jsonl"
    wait_until(
        lambda: (
            proc.poll() is not None
            or (poses.is_file() and len(poses.read_text().splitlines()) >= 10)
        ),
        "10 frames written",
        timeout_s=120,
    )
    assert proc.poll() is None, proc.communicate()
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err
    assert "Traceback" not in err and "interrupted" in out + err
    frames = [f for f, _, _ in read_poses(poses)]
    assert 10 <= len(frames) < 100 and frames == list(range(len(frames)))
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["interrupted"] and summary["frames"] == len(frames)
    with sqlite3.connect(tmp_path / "out" / "events.sqlite") as db:
        db.execute("select count(*) from events").fetchone()
    read_events(tmp_path / "out" / "events.jsonl")
    video = cv2.VideoCapture(str(tmp_path / "out" / "overlays" / "cam01.mp4"))
    assert int(video.get(cv2.CAP_PROP_FRAME_COUNT)) == len(frames)
    assert (tmp_path / "out" / "report.html").is_file()


def test_missing_camera_file_is_a_clear_error(tmp_path: Path, capsys) -> None:
    cfg = _config(tmp_path, sources={"cam02": tmp_path / "gone" / "cam02.mp4"})
    assert main(["run", str(cfg)]) == 2
    err = " ".join(capsys.readouterr().err.split())
    assert "cam02.mp4: video file not found" in err


def test_bad_run_configurations_are_clear_errors(tmp_path: Path, capsys) -> None:
    def error(cfg: Path) -> str:
        assert main(["run", str(cfg)]) == 2
        return " ".join(capsys.readouterr().err.split())

    assert "at least 2 [[cameras]]" in error(_config(tmp_path, cameras=("cam01",)))
    assert "cam09 not in the calibration" in error(_config(tmp_path, cameras=("cam01", "cam09")))
    assert "unknown key(s) colour" in error(_config(tmp_path, extra="\n[outputs]\ncolour = 1\n"))
    assert "detector.imgsz: expected an integer" in error(
        _config(tmp_path, extra='\n[detector]\nimgsz = "big"\n')
    )
    small = tmp_path / "small.mp4"
    writer = cv2.VideoWriter(str(small), cv2.VideoWriter_fourcc(*"mp4v"), 25.0, (64, 48))
    writer.write(np.zeros((48, 64, 3), np.uint8))
    writer.release()
    assert "camera cam02: frames are 64x48 pixels but its calibration is for 1088x1920" in error(
        _config(tmp_path, sources={"cam02": small})
    )
    blocker = tmp_path / "a_file"
    blocker.write_text("")
    cfg = _config(tmp_path)
    cfg.write_text(cfg.read_text().replace(str(tmp_path / "out"), str(blocker / "out")))
    assert "cannot create the output folder" in error(cfg)
    swapped = _config(
        tmp_path,
        sources={
            "cam01": pose2sim_demo_dir() / "Demo_MultiPerson" / "videos" / "cam02.mp4",
        },
    )
    assert main(["run", str(swapped)]) == 0  # same size: fine (the names are the user's)
    capsys.readouterr()


def test_init_writes_a_config_that_run_reads(tmp_path: Path, capsys) -> None:
    path = tmp_path / "site1.toml"
    assert main(["init", str(path)]) == 0
    assert main(["init", str(path)]) == 2
    assert "already exists" in capsys.readouterr().err
    from stereopose.config import load_config

    cfg = load_config(path)
    assert [c.name for c in cfg.cameras] == ["cam01", "cam02"] and cfg.detector.backend == "auto"
    assert main(["run", str(path)]) == 2  # the example's calibration does not exist here
    assert "calib.toml" in capsys.readouterr().err


def test_report_is_rebuilt_from_a_run_folder(real_demo_dir: Path, tmp_path: Path, capsys) -> None:
    (real_demo_dir / "report.html").unlink()
    assert main(["report", str(real_demo_dir)]) == 0
    assert (real_demo_dir / "report.html").stat().st_size > 1_000_000  # plotly.js inline
    assert main(["report", str(tmp_path)]) == 2
    assert "not a run folder" in capsys.readouterr().err


def _serve_http(video: Path, port: int, name: str) -> subprocess.Popen:
    """ffmpeg streaming ``video`` in a loop, in real time, as MPEG-TS over HTTP."""
    import imageio_ffmpeg

    cmd = [
        imageio_ffmpeg.get_ffmpeg_exe(),
        "-loglevel",
        "error",
        "-re",
        "-stream_loop",
        "-1",
        "-i",
        str(video),
        "-an",
        "-c:v",
        "mpeg1video",
        "-q:v",
        "3",
        "-f",
        "mpegts",
        "-listen",
        "1",
        f"http://127.0.0.1:{port}/{name}.ts",
    ]
    return subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


def test_run_on_live_streams(tmp_path: Path) -> None:
    """Two cameras streamed over HTTP in real time: the run takes their latest frames."""
    import socket

    def _free_port() -> int:
        with socket.socket() as s:
            s.bind(("127.0.0.1", 0))
            return s.getsockname()[1]

    videos = pose2sim_demo_dir() / "Demo_MultiPerson" / "videos"
    ports = {"cam01": _free_port(), "cam02": _free_port()}
    servers = [_serve_http(videos / f"{cam}.mp4", port, cam) for cam, port in ports.items()]
    try:
        for server, port in zip(servers, ports.values(), strict=True):
            wait_until(
                lambda s=server, p=port: listening(p) or s.poll() is not None,
                f"ffmpeg to listen on port {port}",
            )
            assert server.poll() is None, f"ffmpeg exited with {server.returncode}"
        cfg = _config(
            tmp_path,
            sources={c: f"http://127.0.0.1:{p}/{c}.ts" for c, p in ports.items()},
            extra="\n[input]\nmax_frames = 15\n[outputs]\noverlays = false\nreport = false\n",
        )
        assert main(["run", str(cfg)]) == 0
    finally:
        for s in servers:
            s.kill()
            s.wait()
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["live"] and summary["frames"] == 15
    assert all(summary["sources"][c]["dropped"] > 0 for c in ports)  # stale frames dropped
    people = [len(p) for _, _, p in read_poses(tmp_path / "out" / "poses3d.jsonl")]
    assert max(people) >= 2
