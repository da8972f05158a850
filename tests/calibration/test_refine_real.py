"""A camera knocked off and placed again from the people the other cameras see, on the real
demo's detections against its Qualisys calibration. The recording cannot judge a pose to a
tenth of a degree (Qualisys's own poses leave 10.5 px median reprojection on these people,
and placing a camera again from Qualisys's pose already moves it 0.5-3.5 degrees;
benchmarks/results/calibration_people.md), so the test asks what it can: a pose knocked by
1.5 degrees and 10 cm comes back to where the people put it from Qualisys's own pose, and
fits the people at least as well as Qualisys's."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from stereopose.calibration.formats import load_calibration
from stereopose.calibration.refine import joints_of_others, pose_error, refine_rig
from stereopose.cli.calibrate_site import _frames
from stereopose.sim.yard import bump
from stereopose.types import Rig

pytestmark = pytest.mark.realdata


def _angle(a, b) -> float:
    return float(np.degrees(np.linalg.norm(cv2.Rodrigues(a.R @ b.R.T)[0])))


@pytest.mark.parametrize("name", ["cam02", "cam04"])
def test_a_knocked_camera_comes_back_on_the_real_demo(shared_data_dir, name) -> None:
    rig = load_calibration(shared_data_dir / "calib.toml")
    frames = _frames(shared_data_dir / "pose", rig, 100)
    settled, _ = refine_rig(rig, [name], frames)  # where the people put it from Qualisys's
    knocked = Rig(
        tuple(bump(c, np.random.default_rng(1), 1.5, 0.1) if c.name == name else c for c in rig)
    )
    assert _angle(knocked[name], rig[name]) > 1.4
    new, done = refine_rig(knocked, [name], frames)
    assert _angle(new[name], settled[name]) < 0.3, done[name]
    assert _angle(new[name], rig[name]) < 1.5  # the recording's own spread (see the module)
    assert all(new[n] is knocked[n] for n in rig.names if n != name)  # the others stay
    pairs = joints_of_others(rig, name, frames)
    q_rms, q_joints = pose_error(rig[name], pairs)
    rms, joints = pose_error(new[name], pairs)
    assert rms <= q_rms and joints >= 0.95 * q_joints, (rms, joints, q_rms, q_joints)
