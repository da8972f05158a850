"""Round trips over random rigs: project, undistort, triangulate -> the point comes back."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from stereopose.geometry.camera import (
    distort,
    project,
    undistort_normalized,
    undistort_pixels,
)
from stereopose.geometry.epipolar import fundamental_matrix, symmetric_epipolar_distance
from stereopose.geometry.triangulation import triangulate_dlt
from stereopose.types import Camera


def random_camera(rng: np.random.Generator, name: str = "cam", k1_range=(-0.3, 0.05)) -> Camera:
    """A camera 4-7 m from the origin looking at it, with realistic distortion."""
    d = rng.uniform(4, 7)
    az, el = rng.uniform(0, 2 * np.pi), rng.uniform(0.2, 0.8)
    C = d * np.array([np.cos(az) * np.cos(el), np.sin(az) * np.cos(el), np.sin(el)])
    fwd = -C / np.linalg.norm(C)
    right = np.cross(fwd, [0, 0, 1.0])
    right /= np.linalg.norm(right)
    down = np.cross(fwd, right)
    R = np.stack([right, down, fwd])
    f = rng.uniform(900, 1600)
    K = [[f, 0, 960 + rng.uniform(-20, 20)], [0, f, 540 + rng.uniform(-20, 20)], [0, 0, 1]]
    dist = [rng.uniform(*k1_range), rng.uniform(0, 0.1), *rng.uniform(-1e-3, 1e-3, 2)]
    return Camera(name, (1920, 1080), K, dist, R, -R @ C)


seeds = st.integers(0, 2**32 - 1)


@settings(max_examples=40, deadline=None)
@given(seeds)
def test_project_matches_opencv(seed):
    rng = np.random.default_rng(seed)
    cam = random_camera(rng)
    X = rng.uniform(-1.5, 1.5, (50, 3))
    ours = project(X, cam)
    ref = cv2.projectPoints(X, cam.rotation, cam.translation, cam.matrix, cam.distortions)[0]
    np.testing.assert_allclose(ours, ref.reshape(-1, 2), atol=1e-6)


@settings(max_examples=40, deadline=None)
@given(seeds)
def test_undistort_inverts_distort(seed):
    rng = np.random.default_rng(seed)
    cam = random_camera(rng)
    xy = rng.uniform(-0.5, 0.5, (100, 2))
    pix = cam.matrix[:2, :2] @ distort(xy, cam.distortions).T + cam.matrix[:2, 2:3]
    np.testing.assert_allclose(undistort_normalized(pix.T, cam), xy, atol=1e-9)


@settings(max_examples=40, deadline=None)
@given(seeds, st.integers(2, 10))
def test_triangulation_round_trip(seed, num_cameras):
    rng = np.random.default_rng(seed)
    cams = [random_camera(rng, f"c{i}") for i in range(num_cameras)]
    X = rng.uniform(-1.5, 1.5, (7, 17, 3))
    xy = np.stack([undistort_normalized(project(X, c), c) for c in cams], axis=-2)
    P = np.stack([c.P for c in cams])
    w = rng.uniform(0.1, 1.0, xy.shape[:-1])
    np.testing.assert_allclose(triangulate_dlt(xy, P, w), X, atol=1e-7)


def test_triangulation_ignores_missing_views_and_needs_two():
    rng = np.random.default_rng(3)
    cams = [random_camera(rng, f"c{i}") for i in range(3)]
    X = rng.uniform(-1, 1, (5, 3))
    xy = np.stack([undistort_normalized(project(X, c), c) for c in cams], axis=-2)
    P = np.stack([c.P for c in cams])
    xy[0, 0] = np.nan  # point 0 unseen in camera 0: still two views
    xy[1, 0] = xy[1, 1] = np.nan  # point 1 in one view only
    w = np.ones(xy.shape[:-1])
    w[2, 2] = 0.0  # weight 0 = unused
    out = triangulate_dlt(xy, P, w)
    np.testing.assert_allclose(out[[0, 2, 3, 4]], X[[0, 2, 3, 4]], atol=1e-8)
    assert np.isnan(out[1]).all()


def test_triangulation_rejects_wrong_shapes():
    with pytest.raises(ValueError, match=r"P must have shape \(\.\.\., 3, 3, 4\)"):
        triangulate_dlt(np.zeros((5, 3, 2)), np.zeros((2, 3, 4)), np.ones((5, 3)))
    with pytest.raises(ValueError, match=r"xy must have shape"):
        triangulate_dlt(np.zeros((5, 3, 3)), np.zeros((3, 3, 4)), np.ones((5, 3)))


@settings(max_examples=30, deadline=None)
@given(seeds)
def test_fundamental_matrix_epipolar_constraint(seed):
    rng = np.random.default_rng(seed)
    a, b = random_camera(rng, "a"), random_camera(rng, "b")
    X = rng.uniform(-1.5, 1.5, (40, 3))
    ua, ub = undistort_pixels(project(X, a), a), undistort_pixels(project(X, b), b)
    F = fundamental_matrix(a, b)
    assert symmetric_epipolar_distance(ua, ub, F).max() < 1e-6
    # a point off its epipolar line is measured in pixels
    shifted = ub + np.array([0.0, 25.0])
    assert np.median(symmetric_epipolar_distance(ua, shifted, F)) > 1.0


def test_points_behind_the_camera_project_to_nan():
    cam = random_camera(np.random.default_rng(0))
    behind = cam.center + 2.0 * (cam.center / np.linalg.norm(cam.center))
    assert np.isnan(project(behind[None], cam)).all()


def test_negative_and_nan_weights_leave_a_view_out():
    rng = np.random.default_rng(9)
    cams = [random_camera(rng, f"c{i}") for i in range(3)]
    X = rng.uniform(-1, 1, (4, 3))
    xy = np.stack([undistort_normalized(project(X, c), c) for c in cams], axis=-2)
    xy[:, 2] += 0.05  # camera 2 is wrong everywhere
    P = np.stack([c.P for c in cams])
    for bad in (-1.0, np.nan, 0.0):
        w = np.ones(xy.shape[:-1])
        w[:, 2] = bad
        np.testing.assert_allclose(triangulate_dlt(xy, P, w), X, atol=1e-8)
