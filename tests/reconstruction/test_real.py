"""Reconstruction of real YOLO11n-pose detections of the pose2sim multi-person demo."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from stereopose.calibration.formats import load_calibration
from stereopose.config import ReconstructionConfig, TriangulationConfig
from stereopose.detection.openpose import read_pose_dir
from stereopose.reconstruction import Reconstructor

pytestmark = pytest.mark.realdata


@pytest.fixture(scope="module")
def real(shared_data_dir: Path):
    rig = load_calibration(shared_data_dir / "calib.toml")
    return rig, list(read_pose_dir(shared_data_dir / "pose", rig.names))


def test_two_people_reconstructed_with_small_reprojection_error(real) -> None:
    rig, frames = real
    rec = Reconstructor(rig)
    out = [rec(f, d) for f, d in frames]
    assert sum(len(o) >= 2 for o in out) >= 95
    confident = np.concatenate([o.reprojection_px[o.conf > 0.5] for o in out])
    assert np.median(confident) <= 6.0
    # people stand on the floor and have human heights
    for o in out:
        for J in o.joints:
            z = J[:, 2][np.isfinite(J[:, 2])]
            assert z.min() > -0.3 and 0.8 < z.max() - z.min() < 2.2


@pytest.mark.parametrize("mode", ["pair", "weighted"])
def test_other_modes_run_on_real_data(real, mode: str) -> None:
    rig, frames = real
    rec = Reconstructor(rig, ReconstructionConfig(triangulation=TriangulationConfig(mode=mode)))
    out = [rec(f, d) for f, d in frames[:20]]
    assert sum(len(o) >= 2 for o in out) == 20


def test_qualisys_calibration_reconstructs_the_same(real, pose2sim_dir: Path) -> None:
    rig, frames = real
    qca = load_calibration(pose2sim_dir / "Demo_MultiPerson" / "calibration" / "Calib.qca.txt")
    assert qca.names == rig.names
    a = Reconstructor(rig)(frames[10][0], frames[10][1])
    b = Reconstructor(qca)(frames[10][0], frames[10][1])
    np.testing.assert_allclose(a.joints, b.joints, atol=1e-6, equal_nan=True)
