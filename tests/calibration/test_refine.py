"""A camera bumped (1.5 degrees, 0.3 m) placed again from the people the other cameras see:
back within 0.1 degrees, the others unchanged."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from stereopose.calibration.refine import refine_rig
from stereopose.errors import CalibrationError
from stereopose.sim.yard import bump, yard_scene
from stereopose.types import Rig

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def yard():
    return yard_scene(seed=2, walkers=2, duration_s=30.0)


def _frames(yard) -> list:
    return [(t, yard.detections[t]) for t in range(0, len(yard.detections), 4)]


def _angle(a, b) -> float:
    return float(np.degrees(np.linalg.norm(cv2.Rodrigues(a.R @ b.R.T)[0])))


def test_a_bumped_camera_comes_back_and_the_others_stay(yard) -> None:
    truth = yard.rig
    knocked = Rig(
        tuple(
            bump(c, np.random.default_rng(9), 1.5, 0.3) if c.name == "cam03" else c for c in truth
        )
    )
    assert _angle(knocked["cam03"], truth["cam03"]) > 1.4
    new, done = refine_rig(knocked, ["cam03"], _frames(yard))
    assert _angle(new["cam03"], truth["cam03"]) < 0.1
    assert np.linalg.norm(new["cam03"].center - truth["cam03"].center) < 0.05
    assert done["cam03"].turned_deg > 1.4 and done["cam03"].rms_px < 4.0
    for cam in truth:
        if cam.name != "cam03":
            assert new[cam.name] is knocked[cam.name]


def test_refining_all_but_one_camera_is_refused(yard) -> None:
    with pytest.raises(CalibrationError, match="at least 2 must stay"):
        refine_rig(yard.rig, list(yard.rig.names[:-1]), _frames(yard))


def test_an_unknown_camera_is_named(yard) -> None:
    with pytest.raises(CalibrationError, match="no camera cam42"):
        refine_rig(yard.rig, ["cam42"], _frames(yard))
