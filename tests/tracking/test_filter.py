"""The per-joint Kalman filter: noise reduction, lag, gating, missing joints."""

from __future__ import annotations

import numpy as np
import pytest

from stereopose.tracking.filter import JointFilters

FPS = 25.0


def run(truth: np.ndarray, noisy: np.ndarray, q: float = 5.0, r: float = 0.03) -> np.ndarray:
    """Filter one person's joints (F, 17, 3) frame by frame; the estimate after each frame."""
    f = JointFilters.empty()
    f.append(noisy[0][None], r)
    out = [f.x[0].copy()]
    for z in noisy[1:]:
        f.predict(1.0 / FPS, q)
        f.update(np.array([0]), z[None], r, 0.25, 4.0, 3)
        out.append(f.x[0].copy())
    return np.array(out)


def walking(frames: int, speed: float = 1.2) -> np.ndarray:
    t = np.arange(frames) / FPS
    base = np.random.default_rng(0).uniform(-0.5, 0.5, (17, 3))
    return base[None] + (speed * t)[:, None, None] * np.array([1.0, 0.0, 0.0])


def test_noise_is_reduced_and_constant_velocity_has_no_lag() -> None:
    truth = walking(250)
    noise = np.random.default_rng(1).normal(0.0, 0.02, truth.shape)
    est = run(truth, truth + noise)
    raw_rms = np.sqrt((noise[50:] ** 2).sum(-1).mean())
    err = est[50:] - truth[50:]
    assert np.sqrt((err**2).sum(-1).mean()) < 0.8 * raw_rms
    # lag: the mean error along the motion stays within a few millimetres
    assert abs(err[..., 0].mean()) < 0.003


def test_turn_lag_is_bounded() -> None:
    """A hand going up and down (0.5 m, 1 Hz): the estimate lags by under 2 frames."""
    t = np.arange(200) / FPS
    truth = np.zeros((200, 17, 3))
    truth[..., 2] = 1.0 + 0.25 * np.sin(2 * np.pi * 1.0 * t)[:, None]
    est = run(truth, truth)
    # the estimate's best-fitting delay
    z, e = truth[50:, 0, 2], est[50:, 0, 2]
    lags = [np.abs(np.roll(z, k)[5:] - e[5:]).mean() for k in range(0, 5)]
    assert int(np.argmin(lags)) <= 1
    assert np.abs(e - z).max() < 0.05


def test_a_one_frame_jump_is_gated_a_lasting_one_is_followed() -> None:
    truth = np.zeros((60, 17, 3))
    meas = truth.copy()
    meas[30, 9] += [0.0, 0.0, 1.0]  # a wrist jumps 1 m for one frame
    est = run(truth, meas)
    assert np.abs(est[30, 9]).max() < 0.01
    meas[40:, 9] += [0.0, 0.0, 1.0]  # and now stays there
    est = run(truth, meas)
    assert np.abs(est[45:, 9, 2] - 1.0).max() < 0.01


def test_missing_joints_are_predicted_and_new_joints_start_at_their_measurement() -> None:
    f = JointFilters.empty()
    z = np.full((1, 17, 3), np.nan)
    z[0, :5] = [1.0, 2.0, 1.5]
    f.append(z, 0.03)
    assert np.isnan(f.x[0, 5:]).all()
    f.predict(0.04, 5.0)
    z2 = z.copy()
    z2[0, 5] = [1.0, 2.0, 1.2]
    used = f.update(np.array([0]), z2, 0.03, 0.25, 4.0, 3)
    assert used[0, :6].all() and not used[0, 6:].any()
    np.testing.assert_allclose(f.x[0, 5], [1.0, 2.0, 1.2])
    assert np.isfinite(f.x[0, :6]).all() and np.isnan(f.x[0, 6:]).all()


@pytest.mark.parametrize("dt", [0.04, 0.5])
def test_uncertainty_grows_with_prediction_time(dt: float) -> None:
    f = JointFilters.empty()
    f.append(np.zeros((1, 17, 3)), 0.03)
    before = f.p00.copy()
    f.predict(dt, 5.0)
    assert (f.p00 > before).all()


def test_people_are_kept_and_dropped_by_mask() -> None:
    f = JointFilters.empty()
    f.append(np.zeros((3, 17, 3)) + np.arange(3)[:, None, None], 0.03)
    f.keep(np.array([True, False, True]))
    assert len(f) == 2
    np.testing.assert_allclose(f.x[:, 0, 0], [0.0, 2.0])


def test_bad_rows_and_shapes_are_clear_errors() -> None:
    f = JointFilters.empty()
    f.append(np.zeros((2, 17, 3)), 0.03)
    with pytest.raises(IndexError, match=r"rows must lie in \[0, 2\), got 0\.\.2"):
        f.update(np.array([0, 2]), np.zeros((2, 17, 3)), 0.03, 0.25, 4.0, 3)
    with pytest.raises(ValueError, match=r"z must have shape \(1, 17, 3\), got \(1, 16, 3\)"):
        f.update(np.array([1]), np.zeros((1, 16, 3)), 0.03, 0.25, 4.0, 3)
