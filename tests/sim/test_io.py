from __future__ import annotations

import json

import numpy as np
import pytest

from stereopose.sim import simulate
from stereopose.sim.io import write_scene

formats = pytest.importorskip("stereopose.calibration.formats")
openpose = pytest.importorskip("stereopose.detection.openpose")


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
