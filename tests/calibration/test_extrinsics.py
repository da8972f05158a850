"""The rig from board positions: pose graph, bundle adjustment, world frame."""

from __future__ import annotations

import numpy as np
import pytest

from stereopose.calibration.board import Board
from stereopose.calibration.corners import Corners
from stereopose.calibration.extrinsics import calibrate_extrinsics, rodrigues
from stereopose.calibration.intrinsics import Detection, calibrate_intrinsics
from stereopose.errors import CalibrationError
from stereopose.sim.calibration import board_scene, close_views, corner_observations
from stereopose.sim.scene import make_rig

BOARD = Board(14, 10, 0.05)  # the reference board: 15 x 11 squares of 50 mm


@pytest.fixture(scope="module")
def synthetic():
    rig = make_rig(6, np.random.default_rng(3))
    rng = np.random.default_rng(0)
    scene = board_scene(rig, BOARD, 20, rng)
    obs = corner_observations(rig, scene, 0.2, rng)  # detected corners: about 0.1 px
    # on this board (15 x 11 squares) the detector may hand over any view's corners in the
    # half-turned order; the floor position's order defines the world's origin and x axis
    for cam in obs:
        for v in list(obs[cam]):
            if v != scene.floor and rng.random() < 0.5:
                obs[cam][v] = obs[cam][v][::-1].copy()
    return rig, scene, obs


def angle_deg(Ra, Rb) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(Ra.T @ Rb) - 1) / 2, -1, 1))))


def check(result, rig, scene, centre_m=0.01, rot_deg=0.2) -> None:
    for cam in rig:
        got = result.rig[cam.name]
        assert np.linalg.norm(got.center + scene.origin - cam.center) < centre_m, cam.name
        assert angle_deg(got.R, cam.R) < rot_deg, cam.name


def test_rig_recovered_with_known_intrinsics(synthetic) -> None:
    rig, scene, obs = synthetic
    result = calibrate_extrinsics({c.name: c for c in rig}, obs, BOARD, floor=scene.floor)
    check(result, rig, scene)
    assert result.rms_px < 0.6 and not result.warnings
    # the floor board lies at z = 0 in the world frame
    floor = result.board_poses[scene.floor]
    corners = BOARD.object_points() @ floor[:3, :3].T + floor[:3, 3]
    assert np.abs(corners[:, 2]).max() < 0.005


@pytest.mark.slow
def test_intrinsics_then_refined_with_the_rig(synthetic) -> None:
    """Zhang per camera from 15 photos of the board held close to it, then one adjustment of
    every camera pose and board position (intrinsics held, the default; then refined)."""
    rig, scene, obs = synthetic
    cams = {}
    joint = {k: dict(v) for k, v in obs.items()}
    rng = np.random.default_rng(5)
    for cam in rig:
        close = close_views(cam, BOARD, 15, 0.2, rng)
        dets = [
            Detection(v, (1920, 1080), Corners(p, "synthetic", 0.0, 40.0)) for v, p in close.items()
        ]
        cams[cam.name] = calibrate_intrinsics(cam.name, dets, BOARD).camera
        joint[cam.name].update({f"{cam.name}:{v}": p for v, p in close.items()})
    # the close-ups adjusted with the rig, intrinsics refined: the targets
    result = calibrate_extrinsics(cams, joint, BOARD, floor=scene.floor, refine_intrinsics=True)
    for cam in rig:
        fx = result.rig[cam.name].matrix[0, 0]
        assert fx == pytest.approx(cam.matrix[0, 0], rel=0.005), cam.name
    check(result, rig, scene)
    # intrinsics held from the close-ups: the focal lengths as estimated, centres a little off
    held = calibrate_extrinsics(cams, obs, BOARD, floor=scene.floor)
    check(held, rig, scene, centre_m=0.02)


def test_world_origin_and_yaw(synthetic) -> None:
    rig, scene, obs = synthetic
    cams = {c.name: c for c in rig}
    a = calibrate_extrinsics(cams, obs, BOARD, floor=scene.floor)
    b = calibrate_extrinsics(cams, obs, BOARD, floor=scene.floor, origin_m=(1.0, 0.5), yaw_deg=90)
    for cam in rig:
        ca, cb = a.rig[cam.name].center, b.rig[cam.name].center
        # shifted by (1, 0.5) then turned by 90 degrees about z
        x, y = ca[0] - 1.0, ca[1] - 0.5
        assert cb == pytest.approx([y, -x, ca[2]], abs=1e-6)


def test_missing_links_and_names_are_clear_errors(synthetic) -> None:
    rig, scene, obs = synthetic
    cams = {c.name: c for c in rig}
    lonely = {k: dict(v) for k, v in obs.items()}
    lonely["cam99"] = {"elsewhere": next(iter(obs["cam01"].values()))}
    cams99 = dict(cams, cam99=rig[0])
    with pytest.raises(CalibrationError, match="camera cam99: it shares no board position"):
        calibrate_extrinsics(cams99, lonely, BOARD, floor=scene.floor)
    with pytest.raises(CalibrationError, match="floor position 'nowhere'"):
        calibrate_extrinsics(cams, obs, BOARD, floor="nowhere")
    with pytest.raises(CalibrationError, match="no intrinsics for camera"):
        calibrate_extrinsics({"cam01": rig[0]}, obs, BOARD)
    only = {"cam01": obs["cam01"]}
    with pytest.raises(CalibrationError, match="at least 2"):
        calibrate_extrinsics(cams, only, BOARD)
    result = calibrate_extrinsics(cams, obs, BOARD)
    assert any("no floor position named" in w for w in result.warnings)


def test_rodrigues_matches_opencv() -> None:
    import cv2

    r = np.random.default_rng(0).normal(0, 1, (20, 3))
    r[0] = 0.0
    want = np.stack([cv2.Rodrigues(v)[0] for v in r])
    np.testing.assert_allclose(rodrigues(r), want, atol=1e-12)
