"""The command line: output contract, summary, and clear errors on bad input."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from stereopose.cli import main


def reconstruct(calib: Path, pose: Path, out: Path, *extra: str) -> int:
    return main(
        ["reconstruct", "--calib", str(calib), "--pose", str(pose), "--out", str(out), *extra]
    )


@pytest.mark.realdata
def test_reconstruct_real_detections(shared_data_dir: Path, tmp_path: Path, capsys) -> None:
    out = tmp_path / "poses3d.jsonl"
    rc = reconstruct(shared_data_dir / "calib.toml", shared_data_dir / "pose", out)
    assert rc == 0
    printed = capsys.readouterr().out
    assert "frames" in printed and "100" in printed
    assert "median reprojection error" in printed
    lines = [json.loads(line) for line in out.read_text().splitlines()]
    assert [r["frame"] for r in lines] == list(range(100))
    assert lines[1]["t"] == pytest.approx(1 / 25)
    for rec in lines:
        for person in rec["people"]:
            assert isinstance(person["id"], int)
            assert len(person["joints"]) == 17
            for j in person["joints"]:
                assert j is None or (len(j) == 3 and all(isinstance(v, float) for v in j))
    two = sum(len(rec["people"]) >= 2 for rec in lines)
    assert two >= 95


BAD_CALIB = (
    "[cam01]\nname = 'cam01'\n"
    "matrix = [[1000.0, 0.0, 500.0], [0.0, 1000.0, 500.0], [0.0, 0.0, 1.0]]\n"
)


def _write_calib(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


@pytest.mark.realdata
@pytest.mark.parametrize(
    ("setup", "message"),
    [
        (lambda d, t: ["--calib", str(t / "missing.toml")], r"missing\.toml.*not found"),
        (
            lambda d, t: ["--calib", str(_write_calib(t / "bad.toml", BAD_CALIB))],
            r"bad\.toml.*cam01.*missing",
        ),
        (lambda d, t: ["--pose", str(t)], r"no keypoint folder matches a camera"),
        (lambda d, t: ["--pose", str(t / "nowhere")], r"nowhere"),
    ],
)
def test_reconstruct_bad_input_is_a_clear_error(
    shared_data_dir: Path, tmp_path: Path, capsys, setup, message
) -> None:
    args = {
        "--calib": str(shared_data_dir / "calib.toml"),
        "--pose": str(shared_data_dir / "pose"),
        "--out": str(tmp_path / "o.jsonl"),
    }
    extra = setup(shared_data_dir, tmp_path)
    args[extra[0]] = extra[1]
    rc = main(["reconstruct", *[x for kv in args.items() for x in kv]])
    err = capsys.readouterr().err
    assert rc == 2
    assert "Traceback" not in err
    import re

    assert re.search(message, " ".join(err.split()), re.IGNORECASE), err


@pytest.mark.realdata
def test_reconstruct_with_one_camera_folder_fails_clearly(
    shared_data_dir: Path, tmp_path: Path, capsys
) -> None:
    pose = tmp_path / "pose"
    shutil.copytree(shared_data_dir / "pose" / "cam01_json", pose / "cam01_json")
    rc = reconstruct(shared_data_dir / "calib.toml", pose, tmp_path / "o.jsonl")
    assert rc == 2
    assert "at least 2 calibrated cameras" in " ".join(capsys.readouterr().err.split())


@pytest.mark.realdata
def test_malformed_keypoint_file_is_skipped_and_reported(
    shared_data_dir: Path, tmp_path: Path, capsys
) -> None:
    pose = tmp_path / "pose"
    shutil.copytree(shared_data_dir / "pose", pose)
    broken = pose / "cam02_json" / "cam02_000000000010_keypoints.json"
    broken.write_text("{not json")
    out = tmp_path / "o.jsonl"
    rc = reconstruct(shared_data_dir / "calib.toml", pose, out)
    captured = capsys.readouterr()
    assert rc == 0
    assert "skipped" in captured.out
    assert "cam02_000000000010_keypoints.json" in "".join(captured.out.split())
    frames = [json.loads(line)["frame"] for line in out.read_text().splitlines()]
    assert frames == list(range(100))  # the frame is still written from the other cameras


def test_bad_config_key_is_named(tmp_path: Path, capsys) -> None:
    cfg = tmp_path / "c.toml"
    cfg.write_text("[reconstruction.triangulation]\nmodee = 'pair'\n")
    rc = main(["reconstruct", "--calib", "x", "--pose", "y", "--out", "z", "--config", str(cfg)])
    err = " ".join(capsys.readouterr().err.split())
    assert rc == 2
    assert "c.toml" in err and "modee" in err


def test_simulate_then_reconstruct(tmp_path: Path, capsys) -> None:
    scene = tmp_path / "scene"
    args = [
        "--frames",
        "12",
        "--cameras",
        "4",
        "--people",
        "2",
        "--difficulty",
        "easy",
        "--seed",
        "3",
    ]
    assert main(["simulate", str(scene), *args]) == 0
    assert (scene / "calib.toml").is_file() and (scene / "truth.jsonl").is_file()
    assert sorted(p.name for p in (scene / "pose").iterdir()) == [
        "cam01_json",
        "cam02_json",
        "cam03_json",
        "cam04_json",
    ]
    out = tmp_path / "poses.jsonl"
    rc = reconstruct(scene / "calib.toml", scene / "pose", out, "--mode", "weighted")
    assert rc == 0
    assert len(out.read_text().splitlines()) == 12


def test_synthetic_demo_prints_the_accuracy(tmp_path: Path, capsys) -> None:
    rc = main(
        ["demo", "--synthetic", "--out", str(tmp_path), "--frames", "15", "--difficulty", "easy"]
    )
    assert rc == 0
    printed = capsys.readouterr().out
    for word in ("MPJPE", "PCP", "pair", "weighted", "robust", "+ tracking", "Zone events"):
        assert word in printed
    assert (tmp_path / "poses3d_robust.jsonl").is_file()
    assert (tmp_path / "poses3d_robust_tracked.jsonl").is_file()
    assert (tmp_path / "events.jsonl").is_file() and (tmp_path / "scene" / "site.toml").is_file()
    report = (tmp_path / "report.html").read_text()
    assert "Floor map" in report and "3D view" in report


def test_simulate_rejects_bad_counts(tmp_path: Path, capsys) -> None:
    rc = main(["simulate", str(tmp_path), "--cameras", "1"])
    assert rc == 2
    assert "between 2 and 12" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("option", "value", "message"),
    [
        ("--fps", "nan", "--fps: expected a finite number"),
        ("--fps", "-1", "--fps: expected a finite number"),
        ("--fps", "1e400", "--fps: expected a finite number"),
        ("--frames", "0", "--frames must be in 1..100000"),
        ("--frames", "1000000000", "--frames must be in 1..100000"),
    ],
)
def test_simulate_rejects_values_out_of_range(
    tmp_path: Path, capsys, option: str, value: str, message: str
) -> None:
    assert main(["simulate", str(tmp_path / "s"), option, value]) == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "s").exists()


def test_all_keypoint_files_malformed_is_an_error(tmp_path: Path, capsys) -> None:
    calib = tmp_path / "scene"
    assert main(["simulate", str(calib), "--frames", "2", "--cameras", "2", "--people", "1"]) == 0
    for f in (calib / "pose").rglob("*.json"):
        f.write_text("[]")
    rc = reconstruct(calib / "calib.toml", calib / "pose", tmp_path / "o.jsonl")
    err = " ".join(capsys.readouterr().err.split())
    assert rc == 2
    assert "none of the keypoint files could be read" in err and "expected a JSON object" in err


@pytest.mark.realdata
def test_reconstruct_tracks_and_exports(shared_data_dir: Path, tmp_path: Path, capsys) -> None:
    from stereopose.io.exports import read_trc

    out, trc, csv_path, tracks = (
        tmp_path / "p.jsonl",
        tmp_path / "trc",
        tmp_path / "j.csv",
        tmp_path / "tracks.json",
    )
    rc = reconstruct(
        shared_data_dir / "calib.toml",
        shared_data_dir / "pose",
        out,
        *("--fps", "60", "--trc", str(trc), "--csv", str(csv_path), "--tracks", str(tracks)),
    )
    assert rc == 0
    printed = capsys.readouterr().out
    assert "People tracked" in printed and "person_1.trc" in printed
    lines = [json.loads(line) for line in out.read_text().splitlines()]
    assert lines[1]["t"] == pytest.approx(1 / 60, abs=1e-6)
    ids = {p["id"] for rec in lines for p in rec["people"]}
    summary = json.loads(tracks.read_text())
    assert {t["id"] for t in summary} == ids
    assert sorted(p.name for p in trc.iterdir()) == sorted(f"person_{i}.trc" for i in ids)
    for rec in lines[5:]:
        for p in rec["people"]:
            assert len(p["position"]) == 2 and p["speed"] is not None
            assert isinstance(p["predicted"], bool) and -180 <= p["heading_deg"] <= 180
    # the TRC of person 1 holds the JSONL's joints, frame by frame
    frames, _, joints, names, rate = read_trc(trc / "person_1.trc")
    assert rate == 60 and len(names) == 17
    by_frame = {rec["frame"]: p["joints"] for rec in lines for p in rec["people"] if p["id"] == 1}
    for f, J in zip(frames, joints, strict=True):
        want = np.array([j if j else [np.nan] * 3 for j in by_frame[f]], dtype=float)
        np.testing.assert_allclose(J, want, atol=1e-4)
    rows = csv_path.read_text().splitlines()
    assert rows[0] == "frame,t,id,joint,x,y,z,conf"
    joints_in_jsonl = sum(
        j is not None for rec in lines for p in rec["people"] for j in p["joints"]
    )
    assert len(rows) - 1 == joints_in_jsonl


@pytest.mark.realdata
def test_reconstruct_without_tracking(shared_data_dir: Path, tmp_path: Path, capsys) -> None:
    out = tmp_path / "p.jsonl"
    rc = reconstruct(shared_data_dir / "calib.toml", shared_data_dir / "pose", out, "--no-tracking")
    assert rc == 0
    assert "off (ids are per frame)" in capsys.readouterr().out
    first = json.loads(out.read_text().splitlines()[0])
    assert [p["id"] for p in first["people"]] == list(range(len(first["people"])))
    assert all(p["velocity"] is None and p["predicted"] is False for p in first["people"])


SITE = """
fps = 60.0
[[zones]]
name = "treadmill_left"
kind = "energized"
polygon = [[-1.0, -1.0], [0.0, -1.0], [0.0, 1.0], [-1.0, 1.0]]
z = [0.0, 2.5]
margin_m = 0.3
[[zones]]
name = "right_side"
kind = "work_area"
polygon = [[0.0, -1.0], [1.5, -1.0], [1.5, 1.0], [0.0, 1.0]]
z = [0.0, 2.5]
dwell_s = 1.0
"""


@pytest.mark.realdata
def test_reconstruct_with_zones_and_list_events(
    shared_data_dir: Path, tmp_path: Path, capsys
) -> None:
    site = tmp_path / "site.toml"
    site.write_text(SITE)
    out, events, db = tmp_path / "p.jsonl", tmp_path / "e.jsonl", tmp_path / "e.sqlite"
    rc = reconstruct(
        shared_data_dir / "calib.toml",
        shared_data_dir / "pose",
        out,
        *("--site", str(site), "--events", str(events), "--events-db", str(db)),
    )
    assert rc == 0
    printed = capsys.readouterr().out
    assert "zone events" in printed and "enter" in printed
    lines = [json.loads(line) for line in out.read_text().splitlines()]
    assert lines[1]["t"] == pytest.approx(1 / 60, abs=1e-6)  # the site's fps
    ids = {p["id"] for rec in lines for p in rec["people"]}
    evs = [json.loads(line) for line in events.read_text().splitlines()]
    assert {"enter", "dwell"} <= {e["type"] for e in evs}
    assert {e["person"] for e in evs} <= ids  # every event names a tracked person
    for e in evs:  # and that person was in the poses at that frame
        rec = next(r for r in lines if r["frame"] == e["frame"])
        assert e["person"] in {p["id"] for p in rec["people"]}
    assert main(["events", str(db)]) == 0
    assert f"{len(evs)} event(s)" in capsys.readouterr().out
    assert main(["events", str(db), "--type", "enter", "--csv"]) == 0
    rows = capsys.readouterr().out.splitlines()
    assert rows[0].startswith("run,t,frame,person,zone")
    assert len(rows) - 1 == sum(e["type"] == "enter" for e in evs)


@pytest.mark.realdata
def test_bad_site_and_misused_event_options(shared_data_dir: Path, tmp_path: Path, capsys) -> None:
    site = tmp_path / "site.toml"
    site.write_text(SITE.replace("z = [0.0, 2.5]", "z = [2.5, 0.0]", 1))
    args = (shared_data_dir / "calib.toml", shared_data_dir / "pose", tmp_path / "p.jsonl")
    assert reconstruct(*args, "--site", str(site)) == 2
    err = capsys.readouterr().err
    assert "site.toml" in err and "treadmill_left" in err and "Traceback" not in err
    assert reconstruct(*args, "--events", str(tmp_path / "e.jsonl")) == 2
    assert "need a site file" in capsys.readouterr().err
    site.write_text(SITE)
    assert reconstruct(*args, "--site", str(site), "--no-tracking") == 2
    assert "need tracking" in capsys.readouterr().err
    assert reconstruct(*args, "--two-way", "--no-tracking") == 2
    err = capsys.readouterr().err
    assert "two-way smoothing needs tracking" in err and "Traceback" not in err
    assert main(["events", str(tmp_path / "none.sqlite")]) == 2
    assert "not found" in capsys.readouterr().err


@pytest.mark.slow
def test_calibrate_intrinsics_then_extrinsics_from_rendered_photos(tmp_path: Path, capsys) -> None:
    """Photos rendered for three cameras of a simulated rig, through both commands."""
    import cv2

    from stereopose.calibration.board import Board
    from stereopose.calibration.formats import load_calibration
    from stereopose.sim.calibration import Renderer, _sees, board_scene, close_pose
    from stereopose.sim.scene import make_rig

    board = Board(9, 6, 0.1)
    rig = make_rig(3, np.random.default_rng(4))
    rng = np.random.default_rng(1)
    scene = board_scene(rig, board, 8, rng)
    ext_dir, int_dir = tmp_path / "ext", tmp_path / "int"
    for cam in rig:
        r = Renderer(cam, board)
        (ext_dir / cam.name).mkdir(parents=True)
        for name, T in scene.poses.items():
            if _sees(cam, T, board) is not None:  # photos of a camera that saw the board
                cv2.imwrite(str(ext_dir / cam.name / f"{name}.png"), r.render(T, rng))
        # close-ups for the intrinsics: the board 1.2-2.5 m in front of the camera
        (int_dir / f"int_{cam.name}_img").mkdir(parents=True)
        for k in range(8):
            T = close_pose(
                cam, board, rng, depth_m=(1.2, 2.5), spread=0.3 * cam.focal / cam.size[0]
            )
            img = r.render(T, rng)
            cv2.imwrite(str(int_dir / f"int_{cam.name}_img" / f"{k:02d}.png"), img)
    intr = tmp_path / "intrinsics.toml"
    rc = main(
        [
            "calibrate",
            "intrinsics",
            "--images",
            str(int_dir),
            "--board",
            "9x6",
            "--square",
            "0.1",
            "--out",
            str(intr),
            "--report",
            str(tmp_path / "report"),
        ]
    )
    assert rc == 0
    printed = capsys.readouterr().out
    assert "Intrinsics written" in printed and (tmp_path / "report" / "intrinsics.png").is_file()
    got = load_calibration(intr, min_cameras=1)
    for cam in rig:
        assert got[cam.name].matrix[0, 0] == pytest.approx(cam.matrix[0, 0], rel=0.01)
    out = tmp_path / "rig.toml"
    rc = main(
        [
            "calibrate",
            "extrinsics",
            "--images",
            str(ext_dir),
            "--intrinsics",
            str(intr),
            "--board",
            "9x6",
            "--square",
            "0.1",
            "--out",
            str(out),
            "--floor",
            scene.floor,
            "--report",
            str(tmp_path / "report"),
        ]
    )
    assert rc == 0
    assert "Rig written" in capsys.readouterr().out
    assert (tmp_path / "report" / "extrinsics.png").is_file()
    rig2 = load_calibration(out)
    for cam in rig:
        # 3 cameras, 8 positions, 8 close-ups each: a few centimetres (see the benchmark for
        # the full-size rig)
        assert np.linalg.norm(rig2[cam.name].center + scene.origin - cam.center) < 0.06
    # and as OpenCV YAML
    rc = main(
        [
            "calibrate",
            "extrinsics",
            "--images",
            str(ext_dir),
            "--intrinsics",
            str(intr),
            "--board",
            "9x6",
            "--square",
            "0.1",
            "--out",
            str(tmp_path / "yml"),
            "--floor",
            scene.floor,
        ]
    )
    assert rc == 0 and len(load_calibration(tmp_path / "yml")) == 3


def test_calibrate_bad_input_is_a_clear_error(tmp_path: Path, capsys) -> None:
    (tmp_path / "photos").mkdir()
    (tmp_path / "photos" / "a.png").write_bytes(b"not an image")
    args = ["calibrate", "intrinsics", "--images", str(tmp_path / "photos"), "--square", "0.05"]
    assert main([*args, "--board", "15", "--out", str(tmp_path / "o.toml")]) == 2
    assert "COLSxROWS" in capsys.readouterr().err
    assert main([*args, "--board", "14x10", "--out", str(tmp_path / "o.toml")]) == 2
    err = capsys.readouterr().err
    assert "found in 0 of 1" in err and "Traceback" not in err
    assert (
        main(
            [
                "calibrate",
                "intrinsics",
                "--images",
                str(tmp_path / "none"),
                "--board",
                "14x10",
                "--square",
                "0.05",
                "--out",
                str(tmp_path / "o.toml"),
            ]
        )
        == 2
    )
    assert "not a folder of photos" in " ".join(capsys.readouterr().err.split())


@pytest.mark.realdata
@pytest.mark.slow
def test_detect_real_videos(pose2sim_dir: Path, tmp_path: Path, capsys) -> None:
    videos = pose2sim_dir / "Demo_MultiPerson" / "videos"
    out = tmp_path / "pose"
    rc = main(
        [
            "detect",
            "--videos",
            str(videos / "cam01.mp4"),
            str(videos / "cam03.mp4"),
            "--out",
            str(out),
            "--max-frames",
            "3",
        ]
    )
    assert rc == 0
    printed = capsys.readouterr().out
    assert "cam01" in printed and "cam03" in printed and "ms per image" in printed
    assert sorted(p.name for p in out.iterdir()) == ["cam01_json", "cam03_json"]
    files = sorted((out / "cam03_json").iterdir())
    assert [f.name for f in files] == [f"cam03_{i:012d}_keypoints.json" for i in range(3)]
    people = json.loads(files[0].read_text())["people"]
    assert len(people) >= 2 and {"pose_keypoints_2d", "box_xyxy", "score"} <= set(people[0])
    rc = main(
        [
            "detect",
            "--videos",
            str(videos / "cam01.mp4"),
            "--names",
            "north",
            "--out",
            str(out),
            "--max-frames",
            "1",
            "--backend",
            "ultralytics",
            "--imgsz",
            "320",
        ]
    )
    assert rc == 0 and (out / "north_json" / "north_000000000000_keypoints.json").is_file()


@pytest.mark.realdata
@pytest.mark.slow
def test_detect_no_regions_is_whole_frames_and_regions_say_what_they_cost(
    pose2sim_dir: Path, tmp_path: Path, capsys
) -> None:
    import cv2

    from stereopose.detection import make_detector

    video = pose2sim_dir / "Demo_MultiPerson" / "videos" / "cam01.mp4"
    whole, regions = tmp_path / "whole", tmp_path / "regions"
    args = ["detect", "--videos", str(video), "--max-frames", "3"]
    assert main([*args, "--out", str(whole), "--no-regions"]) == 0
    assert "regions:" not in capsys.readouterr().out
    assert main([*args, "--out", str(regions)]) == 0
    assert "% of whole frames' model input" in " ".join(capsys.readouterr().out.split())
    # --no-regions: exactly the detector on each whole frame, as before regions existed
    cap = cv2.VideoCapture(str(video))
    ok, frame = cap.read()
    cap.release()
    assert ok
    (want,) = make_detector().detect([frame])  # the default, as detect runs it
    got = json.loads((whole / "cam01_json" / "cam01_000000000000_keypoints.json").read_text())
    kp = np.array([p["pose_keypoints_2d"] for p in got["people"]]).reshape(-1, 17, 3)
    assert kp.shape[0] == len(want)
    order = np.argsort(-np.array([p["score"] for p in got["people"]]))
    np.testing.assert_allclose(kp[order][..., :2], want.keypoints[..., :2], atol=0.01)
    # regions find the same people here (their first step is a scan of the whole frame)
    first = json.loads((regions / "cam01_json" / "cam01_000000000000_keypoints.json").read_text())
    assert len(first["people"]) == len(want)
    assert main([*args, "--out", str(tmp_path / "x"), "--region-imgsz", "300"]) == 2
    assert "--region-imgsz" in capsys.readouterr().err


def test_detect_bad_input_is_a_clear_error(tmp_path: Path, capsys) -> None:
    junk = tmp_path / "cam09.mp4"
    junk.write_bytes(b"\x00" * 5000)
    assert main(["detect", "--videos", str(junk), "--out", str(tmp_path / "o")]) == 2
    assert "cam09.mp4" in capsys.readouterr().err
    missing = tmp_path / "nothing.mp4"
    assert main(["detect", "--videos", str(missing), "--out", str(tmp_path / "o")]) == 2
    assert "nothing.mp4: video file not found" in " ".join(capsys.readouterr().err.split())
    model = tmp_path / "model.onnx"
    model.write_text("garbage")
    args = ["detect", "--videos", str(junk), "--out", str(tmp_path / "o"), "--model", str(model)]
    assert main(args) == 2
    assert "model.onnx: not a readable ONNX model" in " ".join(capsys.readouterr().err.split())
    assert main([*args[:-2], "--imgsz", "100"]) == 2
    assert "multiple of 32" in capsys.readouterr().err
    blocker = tmp_path / "a_file"
    blocker.write_text("")
    video = tmp_path / "v.mp4"
    import cv2

    w = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"mp4v"), 25.0, (64, 48))
    w.write(np.zeros((48, 64, 3), np.uint8))
    w.release()
    assert main(["detect", "--videos", str(video), "--out", str(blocker / "pose")]) == 2
    assert "cannot write keypoint files" in capsys.readouterr().err


def test_models_lists_the_cached_models(capsys) -> None:
    assert main(["models"]) == 0
    assert "yolo11n-pose.onnx" in capsys.readouterr().out


def test_reconstruct_two_way_exports(shared_data_dir: Path, tmp_path: Path) -> None:
    """--two-way: the TRC and CSV hold the same people, frames and joints as the online poses
    file, smoothed (close to, not equal to, the online joints); the poses file is unchanged."""
    from stereopose.io.exports import read_trc

    online, two = tmp_path / "online", tmp_path / "two"
    for d, extra in ((online, ()), (two, ("--two-way",))):
        d.mkdir()
        rc = reconstruct(
            shared_data_dir / "calib.toml",
            shared_data_dir / "pose",
            d / "p.jsonl",
            *("--fps", "60", "--trc", str(d / "trc"), "--csv", str(d / "j.csv"), *extra),
        )
        assert rc == 0
    assert (online / "p.jsonl").read_text() == (two / "p.jsonl").read_text()
    assert sorted(p.name for p in (two / "trc").iterdir()) == sorted(
        p.name for p in (online / "trc").iterdir()
    )
    f1, _, a, _, _ = read_trc(online / "trc" / "person_1.trc")
    f2, _, b, _, _ = read_trc(two / "trc" / "person_1.trc")
    np.testing.assert_array_equal(f1, f2)
    np.testing.assert_array_equal(np.isnan(a), np.isnan(b))
    d = np.linalg.norm(a - b, axis=-1)
    assert 0.001 < np.nanmedian(d) < 0.05  # smoothed, within a few centimetres
    rows1 = (online / "j.csv").read_text().splitlines()
    rows2 = (two / "j.csv").read_text().splitlines()
    assert len(rows1) == len(rows2) and rows1[0] == rows2[0]
    assert [r.split(",")[:4] for r in rows1] == [r.split(",")[:4] for r in rows2]


@pytest.mark.parametrize(
    ("which", "message"),
    [("calib", "calibration file not found"), ("pose", "keypoints folder not found")],
)
def test_missing_input_is_named_before_the_3d_stage_loads(tmp_path: Path, capsys, which, message):
    calib = tmp_path / "calib.toml"
    calib.write_text("")
    pose = tmp_path / "pose"
    pose.mkdir()
    paths = {"calib": calib, "pose": pose, which: tmp_path / f"missing_{which}"}
    argv = ["reconstruct", "--calib", str(paths["calib"]), "--pose", str(paths["pose"])]
    argv += ["--out", str(tmp_path / "p.jsonl")]
    rc = main(argv)
    err = " ".join(capsys.readouterr().err.split())
    assert rc == 2 and f"missing_{which}: {message}" in err
    # in a fresh process: the error comes before the 3D stage (numba, SciPy) is imported
    code = (
        "import sys; from stereopose.cli import main; rc = main(sys.argv[1:]); "
        "print(rc, [m for m in ('numba', 'scipy', 'stereopose.pipeline') if m in sys.modules])"
    )
    done = subprocess.run([sys.executable, "-c", code, *argv], capture_output=True, text=True)
    assert done.stdout.split() == ["2", "[]"], done.stdout + done.stderr
