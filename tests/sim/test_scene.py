from __future__ import annotations

import numpy as np
import pytest

from stereopose.sim import make_rig, simulate
from stereopose.sim.detections import DetectorNoise, joints_in_view
from stereopose.sim.motion import keep_apart, pose
from stereopose.skeleton import JOINT_INDEX, LIMBS


@pytest.mark.parametrize("num_cameras", [2, 4, 6, 8, 12])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_rig_cameras_see_the_room(num_cameras: int, seed: int) -> None:
    rig = make_rig(num_cameras, np.random.default_rng(seed))
    assert rig.names == tuple(f"cam{k:02d}" for k in range(1, num_cameras + 1))
    centre = np.array([[[6.0, 4.0, 0.0], [6.0, 4.0, 1.0]]])
    assert joints_in_view(centre, rig).all()
    for cam in rig:
        assert cam.size == (1920.0, 1080.0)
        assert 3.0 <= cam.center[2] <= 3.8
        assert 0.0 <= cam.center[0] <= 12.0 and 0.0 <= cam.center[1] <= 8.0
        assert abs(cam.R[0, 2]) < 1e-9  # no roll: image x axis is horizontal
        assert cam.R[1, 2] < 0  # image y points down in the world
        fx, fy = cam.matrix[0, 0], cam.matrix[1, 1]
        assert fx == fy and 750 <= fx <= 1100
        assert abs(cam.matrix[0, 2] - 960) <= 20 and abs(cam.matrix[1, 2] - 540) <= 20
        k1, k2, p1, p2 = cam.distortions
        assert -0.25 <= k1 <= -0.05 and 0 <= k2 <= 0.1 and max(abs(p1), abs(p2)) <= 1e-3


@pytest.mark.parametrize("num_cameras", [0, 1, 13])
def test_rig_rejects_camera_counts(num_cameras: int) -> None:
    with pytest.raises(ValueError, match="between 2 and 12"):
        make_rig(num_cameras, np.random.default_rng(0))


def test_skeletons_are_plausible(mid_scene) -> None:
    truth = mid_scene.truth
    assert truth.shape == (200, 4, 17, 3)
    assert np.array_equal(np.isfinite(truth).all(axis=(2, 3)), mid_scene.present)
    for n, worker in enumerate(mid_scene.workers):
        h = worker.height
        assert 1.55 <= h <= 1.95
        j = truth[mid_scene.present[:, n], n]
        for a, b in LIMBS[:12]:
            length = np.linalg.norm(j[:, a] - j[:, b], axis=-1)
            assert length.std() < 1e-6 * h, (a, b)  # rigid bones
            assert 0.1 * h < length.mean() < 0.3 * h
        ankles = j[:, [JOINT_INDEX["left_ankle"], JOINT_INDEX["right_ankle"]], 2]
        # the stance foot is on the floor (within 1 cm while the weight passes between feet)
        stance = ankles.min(axis=1)
        assert ankles.min() > 0.06 and (np.abs(stance - 0.045 * h) < 0.01).mean() > 0.9
        assert j[..., 2].min() > 0.05  # nothing under the floor
        eyes = j[:, 1, 2]
        assert 0.45 * h < eyes.min() and eyes.max() < 0.96 * h  # bending lowers the head
        assert j[..., 2].max() < 1.2 * h


def test_pose_orientation_reach_and_bend() -> None:
    standing = pose(1.8, [[5.0, 4.0]], 0.0)[0]  # facing +x: the left side is +y
    assert standing[5, 1] > standing[6, 1] and standing[11, 1] > standing[12, 1]
    assert standing[1, 1] > standing[2, 1] and standing[3, 1] > standing[4, 1]
    assert standing[0, 0] > standing[3, 0] + 0.05  # nose ahead of the ears
    shoulders = np.linalg.norm(standing[5] - standing[6])
    hips = np.linalg.norm(standing[11] - standing[12])
    assert shoulders == pytest.approx(0.26 * 1.8) and hips == pytest.approx(0.19 * 1.8)
    one = np.ones(1)
    reach = pose(1.8, [[5.0, 4.0]], 0.0, reach_left=one)[0]
    assert reach[9, 2] > reach[0, 2] + 0.2 and reach[10, 2] < reach[5, 2]
    bent = pose(1.8, [[5.0, 4.0]], 0.0, bend=np.deg2rad(60.0) * one)[0]
    spine = 0.5 * (bent[5] + bent[6]) - 0.5 * (bent[11] + bent[12])
    tilt = np.degrees(np.arctan2(spine[0], spine[2]))
    assert tilt == pytest.approx(60.0, abs=1e-6)
    assert 0.5 * (bent[11, 0] + bent[12, 0]) < 5.0 - 0.1  # hips go back


def test_workers_enter_and_leave_when_configured() -> None:
    scene = simulate(
        num_cameras=2,
        num_people=5,
        num_frames=500,
        seed=11,
        p_enter=1.0,
        p_leave=1.0,
        noise=DetectorNoise.preset("easy"),
    )
    present = scene.present
    assert not present[0].any() and not present[-1].any()
    for n in range(5):
        runs = np.flatnonzero(np.diff(present[:, n].astype(int)))
        assert len(runs) == 2, n  # enters once, leaves once
        assert present[runs[0] + 1 : runs[1] + 1, n].all()


def test_workers_stay_when_configured() -> None:
    scene = simulate(num_cameras=2, num_frames=300, seed=4, p_enter=0.0, p_leave=0.0)
    assert scene.present.all()
    for worker in scene.workers:
        s = worker.signals(scene.num_frames, scene.fps)
        speed = np.hypot(np.diff(s["x"]), np.diff(s["y"])) * scene.fps
        assert speed.max() == pytest.approx(worker.speed) and 1.2 <= worker.speed <= 1.5


def test_presets_and_determinism() -> None:
    a = simulate(difficulty="easy", num_frames=30, seed=2)
    assert len(a.rig) == 4 and a.truth.shape[1] == 2 and list(a.ids) == [1, 2]
    b = simulate(difficulty="easy", num_frames=30, seed=2)
    c = simulate(difficulty="easy", num_frames=30, seed=3)
    assert np.array_equal(a.truth, b.truth, equal_nan=True)
    same = all(
        np.array_equal(a.detections[t][k].keypoints, b.detections[t][k].keypoints, equal_nan=True)
        and np.array_equal(a.detection_truth[t][k], b.detection_truth[t][k])
        for t in range(30)
        for k in a.rig.names
    )
    assert same
    assert not np.array_equal(a.truth, c.truth, equal_nan=True)
    hard = simulate(difficulty="hard", num_frames=5)
    assert len(hard.rig) == 6 and hard.truth.shape[1] == 6
    with pytest.raises(ValueError, match="unknown difficulty"):
        simulate(difficulty="extreme")


def test_motion_does_not_depend_on_camera_count() -> None:
    a = simulate(num_cameras=3, num_frames=40, seed=9)
    b = simulate(num_cameras=7, num_frames=40, seed=9)
    assert np.array_equal(a.truth, b.truth, equal_nan=True)


def test_workers_give_way_instead_of_walking_through_each_other() -> None:
    fps, T = 25.0, 200
    t = np.arange(T) / fps
    # two workers walking head-on along nearly the same line, one standing where they meet
    xy = np.stack(
        [
            np.column_stack([1.0 + 1.3 * t, np.full(T, 4.0)]),
            np.column_stack([11.0 - 1.3 * t, np.full(T, 4.1)]),
            np.column_stack([np.full(T, 6.0), np.full(T, 3.95)]),
        ]
    )
    present = np.ones((3, T), dtype=bool)
    out = keep_apart(xy, present, 0.5, fps, (12.0, 8.0))
    gap = np.linalg.norm(out[:, None] - out[None], axis=-1)[[0, 0, 1], [1, 2, 2]]
    assert gap.min() > 0.48
    assert np.abs(out - xy).max() < 1.0  # stepping aside, not a detour
    speed = np.linalg.norm(np.diff(out, axis=1), axis=-1) * fps
    assert speed.max() < 3.0  # a quick step aside, no jump from one frame to the next
    # workers far apart keep their paths
    apart = xy[:2] + np.array([[[0.0, 0.0]], [[0.0, 3.0]]])
    np.testing.assert_array_equal(keep_apart(apart, present[:2], 0.5, fps, (12.0, 8.0)), apart)


def test_simulated_bodies_do_not_overlap() -> None:
    scene = simulate(num_frames=300, seed=2, difficulty="hard")
    for t in range(scene.num_frames):
        idx = np.flatnonzero(scene.present[t])
        # hip centres; bending moves the hips back up to 0.2 m from where the body stands
        hips = scene.truth[t, idx][:, [11, 12], :2].mean(1)
        d = np.linalg.norm(hips[:, None] - hips[None], axis=-1)
        assert (d[np.triu_indices(len(idx), 1)] > 0.25).all(), t
