"""The rig from surveyed points on a simulated yard: the true poses back, a wrong click named
and left out, a camera with too few points named and the others placed; the points file
checked."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from stereopose.calibration.surveyed import Survey, calibrate_points, read_survey
from stereopose.errors import CalibrationError
from stereopose.sim.yard import rig_errors, survey, yard_rig
from stereopose.types import Camera, Rig


def _bare(rig: Rig) -> Rig:
    """The cameras' intrinsics only (their poses forgotten)."""
    return Rig(
        tuple(Camera(c.name, c.size, c.matrix, c.distortions, [0, 0, 0], [0, 0, 1]) for c in rig)
    )


@pytest.fixture
def yard():
    rng = np.random.default_rng(5)
    rig = yard_rig(rng)
    world, clicks = survey(rig, rng)
    return rig, world, clicks


def test_the_cameras_come_back_from_twelve_points_and_a_wrong_click_is_named(yard) -> None:
    rig, world, clicks = yard
    point = sorted(clicks["cam02"])[2]
    clicks["cam02"][point] = clicks["cam02"][point] + [36.0, -27.0]  # 45 px off
    r = calibrate_points(_bare(rig), Survey(Path("points.toml"), world, clicks))
    assert [(c, p) for c, p, _ in r.left_out] == [("cam02", point)]
    assert r.left_out[0][2] > 30
    for cam in rig:  # the points' own frame: no alignment
        new = r.rig[cam.name]
        turn = np.degrees(np.arccos(np.clip((np.trace(new.R.T @ cam.R) - 1) / 2, -1, 1)))
        assert turn < 0.3, (cam.name, turn)
        assert np.linalg.norm(new.center - cam.center) < 0.15, cam.name
    assert max(r.camera_rms_px.values()) < 3.0


def test_the_rig_agrees_with_the_truth_when_aligned_as_people_would_be(yard) -> None:
    rig, world, clicks = yard
    r = calibrate_points(_bare(rig), Survey(Path("p.toml"), world, clicks))
    e = rig_errors(r.rig, rig)
    assert abs(e["scale"] - 1) < 0.005 and abs(e["floor_m"]) < 0.05


def test_a_camera_with_too_few_points_is_named_and_the_others_are_placed(yard) -> None:
    rig, world, clicks = yard
    clicks["cam04"] = dict(sorted(clicks["cam04"].items())[:4])
    r = calibrate_points(_bare(rig), Survey(Path("p.toml"), world, clicks))
    assert "cam04" not in r.rig.names and len(r.rig) == len(rig) - 1
    why = r.unplaced["cam04"]
    assert "4 surveyed point(s) clicked (P" in why and "calibrate people --points" in why
    assert any(w.startswith("camera cam04 not placed") for w in r.warnings)
    for cam in r.rig:  # the others as well placed as with every camera
        turn = np.degrees(np.arccos(np.clip((np.trace(cam.R.T @ rig[cam.name].R) - 1) / 2, -1, 1)))
        assert turn < 0.3 and np.linalg.norm(cam.center - rig[cam.name].center) < 0.15


def test_no_camera_placed_is_an_error_naming_each(yard) -> None:
    rig, world, clicks = yard
    few = {c: dict(sorted(v.items())[:3]) for c, v in clicks.items()}
    with pytest.raises(CalibrationError, match="no camera can be placed") as e:
        calibrate_points(_bare(rig), Survey(Path("p.toml"), world, few))
    assert all(f"camera {c}: 3 surveyed point(s)" in str(e.value) for c in clicks)


def test_a_camera_with_no_intrinsics_is_named(yard) -> None:
    rig, world, clicks = yard
    clicks["cam99"] = clicks["cam01"]
    with pytest.raises(CalibrationError, match="cam99 have no intrinsics"):
        calibrate_points(_bare(rig), Survey(Path("p.toml"), world, clicks))


@pytest.mark.parametrize(
    ("text", "error"),
    [
        ("", "no \\[points\\] table"),
        ("[points]\nP1 = [1, 2, 3]\n", "no \\[cameras.<name>\\] table"),
        ("[points]\nP1 = [1, 2]\n[cameras.c]\nP1 = [1, 2]\n", "points.P1: expected 3 numbers"),
        ("[points]\nP1 = [1, 2, nan]\n[cameras.c]\nP1 = [1, 2]\n", "points.P1: not a finite"),
        ("[points]\nP1 = [1, 2, 3]\n[cameras.c]\nP2 = [1, 2]\n", "cameras.c.P2: no point 'P2'"),
        ("[points]\nP1 = [1, 2, 3]\n[cameras.c]\nP1 = ['a', 2]\n", "cameras.c.P1: expected 2"),
        ("[points]\nP1 = [1, 2, 3]\n[cameras.c]\nP1 = [1, 2]\n[extra]\n", "unknown table"),
        ("[points\n", "not valid TOML"),
    ],
)
def test_a_malformed_points_file_names_the_file_and_the_key(tmp_path, text, error) -> None:
    path = tmp_path / "points.toml"
    path.write_text(text)
    with pytest.raises(CalibrationError, match=error) as e:
        read_survey(path)
    assert str(path) in str(e.value)
