"""`reconstruct` on hostile keypoint folders: the run goes on, every skip named and counted."""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import pytest

from stereopose.cli import main
from stereopose.sim import simulate
from stereopose.sim.io import write_scene


@pytest.fixture(scope="module")
def scene_dir(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("scene")
    write_scene(
        simulate(num_cameras=3, num_people=2, num_frames=12, seed=4, difficulty="easy"), root
    )
    return root


@pytest.fixture
def scene_copy(scene_dir: Path, tmp_path: Path) -> Path:
    shutil.copytree(scene_dir, tmp_path / "scene")
    return tmp_path / "scene"


def reconstruct(scene: Path, capsys, caplog) -> tuple[int, str]:
    caplog.clear()
    rc = main(
        [
            "reconstruct",
            "--calib",
            str(scene / "calib.toml"),
            "--pose",
            str(scene / "pose"),
            "--out",
            str(scene / "poses.jsonl"),
        ]
    )
    captured = capsys.readouterr()
    text = captured.out + captured.err + caplog.text
    assert "Traceback" not in text
    return rc, " ".join(text.split())


def cam_files(scene: Path, cam: int) -> list[Path]:
    folder = sorted((scene / "pose").iterdir())[cam]
    return sorted(folder.iterdir())


def test_hostile_files_are_skipped_and_the_run_goes_on(scene_copy: Path, capsys, caplog) -> None:
    files = cam_files(scene_copy, 0)
    files[2].write_text("[" * 100_000)
    crowd = {"people": [{"pose_keypoints_2d": [0] * 51}] * 51_000}
    files[3].write_text(json.dumps(crowd, separators=(",", ":")))  # under the size bound
    files[4].unlink()
    if hasattr(os, "mkfifo"):
        os.mkfifo(files[4])
    rc, text = reconstruct(scene_copy, capsys, caplog)
    assert rc == 0
    assert files[2].name in text and "nested too deeply" in text
    assert files[3].name in text and "51000 people in one camera frame" in text
    skipped = 3 if hasattr(os, "mkfifo") else 2
    assert f"{skipped} keypoint file(s) skipped" in text and "cam" in text
    frames = [json.loads(line)["frame"] for line in (scene_copy / "poses.jsonl").open()]
    assert frames == list(range(12))  # the other cameras carry those frames


def test_an_empty_camera_folder_is_named(scene_copy: Path, capsys, caplog) -> None:
    for f in cam_files(scene_copy, 2):
        f.unlink()
    rc, text = reconstruct(scene_copy, capsys, caplog)
    empty = sorted((scene_copy / "pose").iterdir())[2].name.removesuffix("_json")
    assert rc == 0 and f"camera {empty}: no keypoint files" in text


def test_no_camera_with_a_file_is_an_error(scene_copy: Path, capsys, caplog) -> None:
    for cam in range(3):
        for f in cam_files(scene_copy, cam):
            f.unlink()
    rc, text = reconstruct(scene_copy, capsys, caplog)
    assert rc == 2 and "no keypoint files (*.json) in the camera folders" in text
