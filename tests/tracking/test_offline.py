"""Two-way (offline) smoothing: no lag, less noise, no smoothing across a restart."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from stereopose.config import Config
from stereopose.pipeline.stage3d import Stage3D
from stereopose.sim import evaluate, simulate
from stereopose.skeleton import NUM_JOINTS
from stereopose.tracking.filter import JointFilters
from stereopose.tracking.offline import ACCEPTED, NOT_USED, RESTARTED, TrackLog, smooth_track

FPS = 25.0
Q = np.full(NUM_JOINTS, 3.0)


def _walk(n: int = 100, speed: float = 1.2, noise: float = 0.03, seed: int = 0):
    """Every joint moving at constant speed along x, measured with noise."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / FPS
    truth = np.zeros((n, NUM_JOINTS, 3))
    truth[..., 0] = speed * t[:, None]
    return truth, truth + rng.normal(0.0, noise, truth.shape)


def _reach(n: int = 150, noise: float = 0.03, seed: int = 0):
    """Every joint swinging back and forth along x (a hand reaching, 0.3 m at 1 Hz)."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / FPS
    truth = np.zeros((n, NUM_JOINTS, 3))
    truth[..., 0] = 0.3 * np.sin(2.0 * np.pi * t)[:, None]
    ahead = np.sign(np.cos(2.0 * np.pi * t))[:, None]  # the direction of motion
    return truth, truth + rng.normal(0.0, noise, truth.shape), ahead


def _log(meas, codes=None, noise: float = 0.03) -> TrackLog:
    log = TrackLog()
    for k, z in enumerate(meas):
        code = np.full(NUM_JOINTS, ACCEPTED if k else RESTARTED) if codes is None else codes[k]
        log.add(k, z, code, np.full(NUM_JOINTS, noise))
    return log


def _online(meas, noise: float = 0.03):
    f = JointFilters.empty()
    f.append(meas[:1], noise)
    out = [f.x[0].copy()]
    for z in meas[1:]:
        f.predict(1.0 / FPS, Q)
        f.update(np.array([0]), z[None], noise, 0.25, 4.0, 3)
        out.append(f.x[0].copy())
    return np.stack(out)


def test_two_way_has_no_lag_and_less_noise_than_online():
    truth, meas, ahead = _reach()
    frames, two = smooth_track(_log(meas), FPS, Q)
    np.testing.assert_array_equal(frames, np.arange(len(meas)))
    online = _online(meas)
    body = slice(10, 140)  # away from the ends, where one side has no data
    # how far each estimate trails the joint, along its motion
    trail_online = np.mean((truth[body, :, 0] - online[body, :, 0]) * ahead[body])
    trail_two = np.mean((truth[body, :, 0] - two[body, :, 0]) * ahead[body])
    assert trail_online > 0.005
    assert abs(trail_two) < 0.3 * trail_online
    err_two = np.linalg.norm(two[body] - truth[body], axis=-1).mean()
    err_online = np.linalg.norm(online[body] - truth[body], axis=-1).mean()
    err_raw = np.linalg.norm(meas[body] - truth[body], axis=-1).mean()
    assert err_two < 0.8 * err_online < err_raw


def test_a_restart_is_not_smoothed_across_and_gaps_are_bridged():
    _, meas = _walk(60, speed=0.0, noise=0.005)
    meas[30:, :, 2] += 1.0  # a joint that jumps and stays there: the filter restarted it
    codes = np.full((60, NUM_JOINTS), ACCEPTED)
    codes[0] = codes[30] = RESTARTED
    codes[40:45] = NOT_USED  # gated out or unseen
    meas[40:45] = np.nan
    _, two = smooth_track(_log(meas, codes), FPS, Q)
    assert np.abs(two[:30, :, 2]).max() < 0.02  # nothing of the jump leaks backwards
    assert np.abs(two[30:, :, 2] - 1.0).max() < 0.02
    assert np.isfinite(two[40:45]).all()


def test_joints_before_their_first_and_after_their_last_measurement_are_not_invented():
    _, meas = _walk(20)
    codes = np.full((20, NUM_JOINTS), ACCEPTED)
    codes[0] = RESTARTED
    codes[15:, 9] = NOT_USED
    meas[15:, 9] = np.nan
    codes[:5, 10] = NOT_USED
    codes[5, 10] = RESTARTED
    meas[:5, 10] = np.nan
    _, two = smooth_track(_log(meas, codes), FPS, Q)
    assert np.isnan(two[15:, 9]).all() and np.isfinite(two[:15, 9]).all()
    assert np.isnan(two[:5, 10]).all() and np.isfinite(two[5:, 10]).all()


def test_tracker_two_way_lowers_the_error_and_keeps_people_and_frames():
    scene = simulate(num_frames=150, seed=2, difficulty="mid")
    frames = [[d[n] for n in scene.rig.names] for d in scene.detections]
    tracker = Stage3D(scene.rig, dataclasses.replace(Config(), fps=scene.fps), record=True)
    online = [tracker.step(t, f) for t, f in enumerate(frames)]
    two = tracker.two_way(online)
    assert [p.frame for p in two] == [p.frame for p in online]
    for a, b in zip(online, two, strict=True):
        np.testing.assert_array_equal(a.ids, b.ids)
        np.testing.assert_array_equal(np.isnan(a.joints), np.isnan(b.joints))
    assert evaluate(two, scene).mpjpe_mm < 0.85 * evaluate(online, scene).mpjpe_mm
    with pytest.raises(ValueError, match="record=True"):
        Stage3D(scene.rig).two_way(online)
