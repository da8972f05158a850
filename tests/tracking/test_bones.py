"""Running limb lengths and their enforcement."""

from __future__ import annotations

import numpy as np

from stereopose.tracking.bones import CHILD, PARENT, BoneLengths


def pose(rng: np.random.Generator) -> np.ndarray:
    X = rng.uniform(-1, 1, (17, 3))
    for p, c in zip(PARENT, CHILD, strict=True):  # every limb 0.3 m, random direction
        d = rng.normal(size=3)
        X[c] = X[p] + 0.3 * d / np.linalg.norm(d)
    return X


def test_lengths_converge_and_are_enforced() -> None:
    rng = np.random.default_rng(0)
    b = BoneLengths.empty()
    b.append(1)
    rows = np.array([0])
    for _ in range(100):
        b.observe(rows, (pose(rng) + rng.normal(0, 0.01, (17, 3)))[None])
    np.testing.assert_allclose(b.length[0], 0.3, atol=0.01)
    X = pose(rng)[None]
    X[0, CHILD] = X[0, PARENT] + 1.2 * (X[0, CHILD] - X[0, PARENT])  # limbs 20 % too long
    Y = b.apply(rows, X)
    lengths = np.linalg.norm(Y[0, CHILD] - Y[0, PARENT], axis=-1)
    np.testing.assert_allclose(lengths, b.length[0], atol=1e-9)


def test_outliers_and_missing_joints_do_not_move_the_estimate() -> None:
    rng = np.random.default_rng(1)
    b = BoneLengths.empty()
    b.append(1)
    rows = np.array([0])
    for _ in range(20):
        b.observe(rows, pose(rng)[None])
    far = pose(rng)
    far[CHILD] = far[PARENT] + 3.0 * (far[CHILD] - far[PARENT])
    b.observe(rows, far[None])
    gone = np.full((1, 17, 3), np.nan)
    b.observe(rows, gone)
    np.testing.assert_allclose(b.length[0], 0.3, atol=1e-9)


def test_unknown_lengths_leave_joints_alone() -> None:
    b = BoneLengths.empty()
    b.append(1)
    X = pose(np.random.default_rng(2))[None]
    np.testing.assert_array_equal(b.apply(np.array([0]), X), X)
