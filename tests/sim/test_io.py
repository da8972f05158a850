from __future__ import annotations

import json

import numpy as np
import pytest

from stereopose.calibration import formats
from stereopose.detection import openpose
from stereopose.errors import StereoposeError
from stereopose.sim import simulate
from stereopose.sim.io import write_scene


def test_write_scene_round_trip(tmp_path) -> None:
    scene = simulate(difficulty="easy", num_frames=6, seed=1, p_enter=1.0)
    write_scene(scene, tmp_path)
    rig = formats.load_calibration(tmp_path / "calib.toml")
    assert rig.names == scene.rig.names
    for a, b in zip(rig, scene.rig, strict=True):
        assert np.allclose(a.matrix, b.matrix) and np.allclose(a.translation, b.translation)
    seq = openpose.read_pose_dir(tmp_path / "pose", scene.rig.names)
    assert seq.frames == list(range(6))
    for t in range(6):
        frame = seq.frame(t)
        for name in scene.rig.names:
            want = scene.detections[t][name].keypoints
            assert np.allclose(frame[name].keypoints, want, equal_nan=True, atol=1e-3)
    lines = (tmp_path / "truth.jsonl").read_text().splitlines()
    assert len(lines) == 6
    rec = json.loads(lines[3])
    assert rec["frame"] == 3 and rec["t"] == pytest.approx(3 / 25.0)
    assert len(rec["people"]) == int(scene.present[3].sum())


def test_rewriting_a_scene_replaces_the_old_one(tmp_path) -> None:
    write_scene(simulate(num_cameras=3, num_people=1, num_frames=8, seed=1), tmp_path)
    write_scene(simulate(num_cameras=2, num_people=1, num_frames=4, seed=2), tmp_path)
    seq = openpose.read_pose_dir(tmp_path / "pose", ["cam01", "cam02", "cam03"])
    assert seq.cameras == ("cam01", "cam02")
    assert seq.frames == [0, 1, 2, 3]


def test_a_foreign_pose_folder_is_left_alone(tmp_path) -> None:
    (tmp_path / "pose").mkdir()
    (tmp_path / "pose" / "notes.txt").write_text("mine")
    with pytest.raises(StereoposeError, match="not a keypoints folder"):
        write_scene(simulate(num_cameras=2, num_people=1, num_frames=2, seed=1), tmp_path)
    assert (tmp_path / "pose" / "notes.txt").read_text() == "mine"
