"""OpenCV YAML (EasyMocap intri.yml / extri.yml) import and export."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from stereopose.calibration.formats import load_calibration
from stereopose.calibration.opencv_yaml import write_opencv_yaml
from stereopose.errors import CalibrationError
from stereopose.sim.scene import make_rig


def test_round_trip(tmp_path: Path) -> None:
    rig = make_rig(3, np.random.default_rng(1))
    intri, extri = write_opencv_yaml(tmp_path / "yml", rig)
    assert intri.name == "intri.yml" and extri.name == "extri.yml"
    for path in (tmp_path / "yml", intri, extri):
        back = load_calibration(path)
        for a, b in zip(rig, back, strict=True):
            assert a.name == b.name and a.size == b.size
            np.testing.assert_allclose(a.matrix, b.matrix, rtol=1e-12)
            np.testing.assert_allclose(a.R, b.R, atol=1e-12)
            np.testing.assert_allclose(a.translation, b.translation, atol=1e-12)
            np.testing.assert_allclose(a.distortions[:4], b.distortions[:4], atol=1e-15)
    assert "K_cam01" in intri.read_text() and "Rot_cam01" in extri.read_text()


def test_missing_parts_are_clear_errors(tmp_path: Path) -> None:
    rig = make_rig(2, np.random.default_rng(1))
    intri, extri = write_opencv_yaml(tmp_path, rig)
    extri.write_text(extri.read_text().replace("T_cam02", "X_cam02"))
    with pytest.raises(CalibrationError, match=r"extri\.yml: missing `T_cam02`"):
        load_calibration(intri)
    extri.unlink()
    with pytest.raises(CalibrationError, match=r"extri\.yml: calibration file not found"):
        load_calibration(intri)
