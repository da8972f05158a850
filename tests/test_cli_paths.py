"""Commands never write over their inputs or over each other's outputs, and a folder holds one
run: each collision is a clear error (exit code 2) and nothing the user gave is modified."""

from __future__ import annotations

import contextlib
import os
import shutil
import subprocess
from pathlib import Path

import cv2
import numpy as np
import pytest

from stereopose.cli import main
from stereopose.sim import simulate
from stereopose.sim.io import write_scene

SITE = """fps = 25.0
[[zones]]
name = "bay"
kind = "work_area"
polygon = [[-5.0, -5.0], [5.0, -5.0], [5.0, 5.0], [-5.0, 5.0]]
z = [0.0, 2.5]
"""


@pytest.fixture(scope="module")
def scene_dir(tmp_path_factory) -> Path:
    """A small simulated scene (3 cameras, 2 workers, 10 frames), a site and a configuration."""
    d = tmp_path_factory.mktemp("scene")
    write_scene(simulate(num_cameras=3, num_people=2, num_frames=10, seed=3, difficulty="easy"), d)
    (d / "site.toml").write_text(SITE)
    (d / "config.toml").write_text("[tracking]\nenabled = true\n")
    return d


def snapshot(root: Path) -> dict[Path, tuple[bytes, int]]:
    """Every file under root (links followed) with its bytes and modification time."""
    return {
        p: (p.read_bytes(), p.stat().st_mtime_ns) for p in sorted(root.rglob("*")) if p.is_file()
    }


def _refused(argv: list[str], capsys, *named: Path) -> str:
    assert main(argv) == 2
    captured = capsys.readouterr()
    err = " ".join(captured.err.split())
    assert "Traceback" not in captured.out + captured.err
    assert err.startswith("error: refusing to write") or "already holds" in err, err
    for p in named:
        assert str(p) in err, (p, err)
    return err


def _reconstruct(scene: Path, *extra: str | Path) -> list[str]:
    return [
        "reconstruct",
        "--calib",
        str(scene / "calib.toml"),
        "--pose",
        str(scene / "pose"),
        *map(str, extra),
    ]


def _links(scene: Path, tmp: Path) -> dict[str, Path]:
    """Other names of the scene's files: symbolic and hard links, a `..` spelling."""
    frame = next((scene / "pose" / "cam01_json").iterdir())
    names = {
        "symlink": tmp / "calib_link.toml",
        "hardlink": tmp / "calib_hard.toml",
        "frame_hardlink": tmp / "frame.json",
    }
    if not names["symlink"].exists():
        names["symlink"].symlink_to(scene / "calib.toml")
        os.link(scene / "calib.toml", names["hardlink"])
        os.link(frame, names["frame_hardlink"])
    return names


COLLISIONS = {
    # case: (options, the paths the message names), relative to the scene ("S") and tmp ("T")
    "out is the calibration": (["--out", "S/calib.toml"], ["S/calib.toml"]),
    "out through a symlink": (["--out", "T/calib_link.toml"], ["S/calib.toml"]),
    "out through a hard link": (["--out", "T/calib_hard.toml"], ["S/calib.toml"]),
    "out through ..": (["--out", "S/pose/../calib.toml"], ["S/calib.toml"]),
    "out inside the keypoints folder": (
        ["--out", "S/pose/cam01_json/cam01_000000000042_keypoints.json"],
        ["S/pose"],
    ),
    "out a hard link to a keypoint file": (["--out", "T/frame.json"], ["T/frame.json"]),
    "trc is the keypoints folder": (["--out", "T/p.jsonl", "--trc", "S/pose"], ["S/pose"]),
    "csv is the site": (
        ["--out", "T/p.jsonl", "--site", "S/site.toml", "--csv", "S/site.toml"],
        ["S/site.toml"],
    ),
    "tracks is the configuration": (
        ["--out", "T/p.jsonl", "--config", "S/config.toml", "--tracks", "S/config.toml"],
        ["S/config.toml"],
    ),
    "events is the poses file": (
        ["--out", "T/p.jsonl", "--site", "S/site.toml", "--events", "T/p.jsonl"],
        ["T/p.jsonl"],
    ),
    "events-db is the poses file": (
        ["--out", "T/p.db", "--site", "S/site.toml", "--events-db", "T/p.db"],
        ["T/p.db"],
    ),
    "csv inside the trc folder": (
        ["--out", "T/p.jsonl", "--trc", "T/trc", "--csv", "T/trc/person_1.trc"],
        ["T/trc"],
    ),
    "csv is the event log's journal": (
        [
            "--out",
            "T/p.jsonl",
            "--site",
            "S/site.toml",
            "--events-db",
            "T/e.db",
            "--csv",
            "T/e.db-wal",
        ],
        ["T/e.db-wal"],
    ),
}


@pytest.mark.parametrize("case", list(COLLISIONS))
def test_reconstruct_refuses_every_collision_and_touches_nothing(
    case: str, scene_dir: Path, tmp_path: Path, capsys
) -> None:
    _links(scene_dir, tmp_path)
    options, named = COLLISIONS[case]

    def path(s: str) -> str:
        return s.replace("S/", f"{scene_dir}/").replace("T/", f"{tmp_path}/")

    before = snapshot(scene_dir), snapshot(tmp_path)
    _refused(_reconstruct(scene_dir, *map(path, options)), capsys, *map(path, named))
    assert (snapshot(scene_dir), snapshot(tmp_path)) == before  # nothing written, nothing new


def test_reconstruct_trc_folder_holds_one_run(scene_dir: Path, tmp_path: Path, capsys) -> None:
    trc = tmp_path / "trc"
    argv = _reconstruct(scene_dir, "--out", tmp_path / "p.jsonl", "--trc", trc)
    assert main(argv) == 0
    first = sorted(p.name for p in trc.iterdir())
    assert first and all(n.startswith("person_") for n in first)
    (trc / "person_99.trc").write_text("a previous run's person\n")
    (trc / "notes.txt").write_text("mine\n")
    before = snapshot(tmp_path)
    err = _refused(argv, capsys, trc)
    assert "--overwrite" in err and "person_99.trc" in err
    assert snapshot(tmp_path) == before
    capsys.readouterr()
    assert main([*argv, "--overwrite"]) == 0
    assert sorted(p.name for p in trc.iterdir()) == sorted([*first, "notes.txt"])
    assert (trc / "notes.txt").read_text() == "mine\n"


def _video(path: Path, frames: int = 2) -> Path:
    w = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), 25.0, (64, 48))
    for _ in range(frames):
        w.write(np.zeros((48, 64, 3), np.uint8))
    w.release()
    return path


def test_detect_never_writes_inside_its_sources(tmp_path: Path, capsys) -> None:
    frames = tmp_path / "cam01"
    frames.mkdir()
    cv2.imwrite(str(frames / "0000.png"), np.zeros((48, 64, 3), np.uint8))
    video = _video(tmp_path / "cam02.mp4")
    before = snapshot(tmp_path)
    argv = ["detect", "--videos", str(frames), str(video), "--imgsz", "64"]
    _refused([*argv, "--out", str(frames / "pose")], capsys, frames)
    _refused([*argv, "--names", "a", "b", "--out", str(tmp_path / "cam02.mp4")], capsys, video)
    assert snapshot(tmp_path) == before


def test_detect_camera_folders_hold_one_run(tmp_path: Path, capsys) -> None:
    video = _video(tmp_path / "cam01.mp4")
    out = tmp_path / "pose"
    argv = ["detect", "--videos", str(video), "--out", str(out), "--imgsz", "64"]
    assert main(argv) == 0
    first = sorted(p.relative_to(out) for p in out.rglob("*.json"))
    assert len(first) == 2
    stale = out / "cam01_json" / "cam01_000000000099_keypoints.json"  # a longer run's frame
    other = out / "cam09_json" / "cam09_000000000000_keypoints.json"  # another camera's
    for p in (stale, other):
        p.parent.mkdir(exist_ok=True)
        p.write_text('{"people": []}')
    (out / "cam01_json" / "notes.txt").write_text("mine\n")
    before = snapshot(tmp_path)
    capsys.readouterr()
    err = _refused(argv, capsys, out)
    assert "cam01_000000000099_keypoints.json" in err and "--overwrite" in err
    assert snapshot(tmp_path) == before
    assert main([*argv, "--overwrite"]) == 0
    assert not stale.exists() and other.exists()
    assert sorted(p.relative_to(out) for p in out.rglob("*.json")) == sorted(
        [*first, other.relative_to(out)]
    )
    assert (out / "cam01_json" / "notes.txt").read_text() == "mine\n"


def test_calibrate_never_writes_over_its_inputs(scene_dir: Path, tmp_path: Path, capsys) -> None:
    photos = tmp_path / "photos"
    (photos / "cam01").mkdir(parents=True)
    intrinsics = tmp_path / "intrinsics.toml"
    intrinsics.write_bytes((scene_dir / "calib.toml").read_bytes())
    before = snapshot(tmp_path)
    board = ["--board", "4x3", "--square", "0.05"]
    ext = ["calibrate", "extrinsics", "--images", str(photos), *board]
    _refused([*ext, "--intrinsics", str(intrinsics), "--out", str(intrinsics)], capsys, intrinsics)
    yml = tmp_path / "yml"
    yml.mkdir()
    (yml / "intri.yml").write_text("%YAML:1.0\n")
    _refused(
        [*ext, "--intrinsics", str(yml), "--out", str(yml / "extri.yml")], capsys, yml / "intri.yml"
    )
    intr = ["calibrate", "intrinsics", "--images", str(photos), *board]
    _refused([*intr, "--out", str(photos / "cam01" / "calib.toml")], capsys, photos)
    _refused(
        [*intr, "--out", str(tmp_path / "c.toml"), "--report", str(photos / "report")],
        capsys,
        photos,
    )
    assert snapshot(tmp_path) == {**before, yml / "intri.yml": snapshot(yml)[yml / "intri.yml"]}


def test_the_demo_replaces_only_its_own_previous_run(tmp_path: Path) -> None:
    from stereopose.cli.run import _previous_demo

    demo = tmp_path / "demo.toml"
    demo.write_text('calibration = "x"\noutput = "."\n')
    assert not _previous_demo(tmp_path, demo)  # nothing there yet
    (tmp_path / "config.toml").write_text('calibration = "y"\noutput = "."\n')
    assert not _previous_demo(tmp_path, demo)  # another run's folder
    (tmp_path / "config.toml").write_text(demo.read_text())
    assert _previous_demo(tmp_path, demo)


def test_the_synthetic_demo_leaves_no_other_mode_s_poses(tmp_path: Path, capsys) -> None:
    argv = ["demo", "--synthetic", "--out", str(tmp_path), "--frames", "6", "--difficulty", "easy"]
    (tmp_path / "notes.txt").write_text("mine\n")
    assert main(argv) == 0
    assert (tmp_path / "poses3d_weighted.jsonl").is_file()
    assert main([*argv, "--mode", "pair"]) == 0
    left = sorted(p.name for p in tmp_path.glob("poses3d_*.jsonl"))
    assert left == ["poses3d_pair.jsonl", "poses3d_pair_tracked.jsonl"]
    assert (tmp_path / "notes.txt").read_text() == "mine\n"


RUN_CALIB = "".join(
    f'[{cam}]\nname = "{cam}"\nsize = [ 64.0, 48.0]\n'
    "matrix = [ [ 50.0, 0.0, 32.0], [ 0.0, 50.0, 24.0], [ 0.0, 0.0, 1.0]]\n"
    f"distortions = [ 0.0, 0.0, 0.0, 0.0]\nrotation = [ 0.0, {ry}, 0.0]\n"
    f"translation = [ {tx}, 0.0, 5.0]\nfisheye = false\n"
    for cam, ry, tx in (("cam01", 0.0, 0.0), ("cam02", 0.5, 1.0))
)


@contextlib.contextmanager
def _read_only_folder(path: Path):
    """`path` a read-only tmpfs for the test (root only: mount(8)); skipped where not allowed."""
    path.mkdir()
    if shutil.which("mount") is None or os.geteuid() != 0:
        pytest.skip("needs root and mount(8) to make a read-only file system")
    done = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", "ro,size=1m", "tmpfs", str(path)],
        capture_output=True,
        text=True,
    )
    if done.returncode != 0:
        pytest.skip(f"mounting a read-only tmpfs is not permitted here: {done.stderr.strip()}")
    try:
        yield path
    finally:
        subprocess.run(["umount", str(path)], check=True)


def test_a_run_into_a_folder_on_a_read_only_file_system_is_exit_2_naming_it(
    tmp_path: Path, capsys
) -> None:
    (tmp_path / "calib.toml").write_text(RUN_CALIB)
    for cam in ("cam01", "cam02"):
        (tmp_path / cam).mkdir()
        for i in range(2):
            cv2.imwrite(str(tmp_path / cam / f"{i:04d}.png"), np.zeros((48, 64, 3), np.uint8))
    cameras = "".join(f'[[cameras]]\nname = "{c}"\nsource = "{c}"\n' for c in ("cam01", "cam02"))
    config = tmp_path / "config.toml"
    config.write_text(
        f'calibration = "calib.toml"\noutput = "out"\n{cameras}'
        "[detector]\nimgsz = 64\n[outputs]\nreport = false\n"
    )
    with _read_only_folder(tmp_path / "out") as out:
        assert main(["run", str(config)]) == 2
        captured = capsys.readouterr()
    assert "Traceback" not in captured.out + captured.err
    err = " ".join(captured.err.split())
    assert err.startswith("error: ") and str(out) in err and "read-only file system" in err, err
