"""Round trips over random rigs: project, undistort, triangulate -> the point comes back."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from stereopose.geometry.camera import (
    distort,
    homogeneous,
    project,
    undistort_normalized,
    undistort_pixels,
)
from stereopose.geometry.epipolar import fundamental_matrix, symmetric_epipolar_distance
from stereopose.geometry.triangulation import triangulate_dlt
from stereopose.types import Camera


def _look_at(azimuth: float, elevation: float, distance: float, roll: float):
    """Rotation and translation (world -> camera) of a camera at ``distance`` m from the origin,
    looking at it from ``azimuth`` and ``elevation`` (rad), turned by ``roll`` (rad) about its
    optical axis."""
    C = distance * np.array(
        [
            np.cos(azimuth) * np.cos(elevation),
            np.sin(azimuth) * np.cos(elevation),
            np.sin(elevation),
        ]
    )
    fwd = -C / np.linalg.norm(C)
    right = np.cross(fwd, [0, 0, 1.0])
    right /= np.linalg.norm(right)
    c, s = np.cos(roll), np.sin(roll)
    R = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]) @ np.stack(
        [right, np.cross(fwd, right), fwd]
    )
    return R, -R @ C


def random_camera(rng: np.random.Generator, name: str = "cam", k1_range=(-0.3, 0.05)) -> Camera:
    """A camera 4-7 m from the origin looking at it, with realistic distortion."""
    d = rng.uniform(4, 7)
    az, el = rng.uniform(0, 2 * np.pi), rng.uniform(0.2, 0.8)
    R, t = _look_at(az, el, d, 0.0)
    f = rng.uniform(900, 1600)
    K = [[f, 0, 960 + rng.uniform(-20, 20)], [0, f, 540 + rng.uniform(-20, 20)], [0, 0, 1]]
    dist = [rng.uniform(*k1_range), rng.uniform(0, 0.1), *rng.uniform(-1e-3, 1e-3, 2)]
    return Camera(name, (1920, 1080), K, dist, R, t)


def _floats(lo: float, hi: float) -> st.SearchStrategy[float]:
    return st.floats(lo, hi, allow_nan=False, allow_infinity=False)


@st.composite
def cameras(draw, name: str = "cam", azimuth: float | None = None) -> Camera:
    """A camera 4-7 m from the origin looking at it (``azimuth`` drawn unless given), with
    realistic intrinsics and distortion; every parameter is a bounded float, so a failing case
    shrinks towards a plain camera."""
    if azimuth is None:
        azimuth = draw(_floats(0, 2 * np.pi))
    R, t = _look_at(azimuth, draw(_floats(0.2, 0.8)), draw(_floats(4, 7)), draw(_floats(-0.3, 0.3)))
    f = draw(_floats(900, 1600))
    fy = f * draw(_floats(0.98, 1.02))
    cx, cy = 960 + draw(_floats(-20, 20)), 540 + draw(_floats(-20, 20))
    dist = [draw(_floats(-0.3, 0.05)), draw(_floats(0, 0.1))]
    dist += [draw(_floats(-1e-3, 1e-3)), draw(_floats(-1e-3, 1e-3))]
    return Camera(name, (1920, 1080), [[f, 0, cx], [0, fy, cy], [0, 0, 1]], dist, R, t)


@st.composite
def rigs(draw, min_cameras: int = 2, max_cameras: int = 10) -> list[Camera]:
    """2-10 cameras around the origin, spread in azimuth (no two views along the same line)."""
    n = draw(st.integers(min_cameras, max_cameras))
    start, gap = draw(_floats(0, 2 * np.pi)), 2 * np.pi / n
    return [
        draw(cameras(f"c{i}", start + gap * (i + draw(_floats(-0.25, 0.25))))) for i in range(n)
    ]


def points(*shape: int | st.SearchStrategy[int], lo: float = -1.5, hi: float = 1.5):
    """Arrays of world points (..., 3), metres, in the cube [lo, hi]^3 about the origin."""
    sides = [s if isinstance(s, st.SearchStrategy) else st.just(s) for s in shape]
    return hnp.arrays(np.float64, st.tuples(*sides, st.just(3)), elements=_floats(lo, hi))


@settings(max_examples=40, deadline=None)
@given(cameras(), points(st.integers(1, 50)))
def test_project_matches_opencv(cam, X):
    ours = project(X, cam)
    ref = cv2.projectPoints(X, cam.rotation, cam.translation, cam.matrix, cam.distortions)[0]
    np.testing.assert_allclose(ours, ref.reshape(-1, 2), atol=1e-6)


@settings(max_examples=40, deadline=None)
@given(
    cameras(),
    hnp.arrays(np.float64, st.tuples(st.integers(1, 100), st.just(2)), elements=_floats(-0.5, 0.5)),
)
def test_undistort_inverts_distort(cam, xy):
    pix = cam.matrix[:2, :2] @ distort(xy, cam.distortions).T + cam.matrix[:2, 2:3]
    np.testing.assert_allclose(undistort_normalized(pix.T, cam), xy, atol=1e-9)


@st.composite
def views(draw, noise: float = 0.0):
    """A rig, world points (A, B, 3), their ideal normalised coordinates in each camera
    (A, B, V, 2), moved by up to ``noise`` (normalised units), and view weights (A, B, V)."""
    cams = draw(rigs())
    X = draw(points(st.integers(1, 6), st.integers(1, 17)))
    xy = np.stack([undistort_normalized(project(X, c), c) for c in cams], axis=-2)
    if noise:
        xy = xy + draw(hnp.arrays(np.float64, xy.shape, elements=_floats(-noise, noise)))
    w = draw(hnp.arrays(np.float64, xy.shape[:-1], elements=_floats(0.1, 1.0)))
    return cams, X, xy, w


@settings(max_examples=40, deadline=None)
@given(views())
def test_triangulation_round_trip(case):
    cams, X, xy, w = case
    P = np.stack([c.P for c in cams])
    np.testing.assert_allclose(triangulate_dlt(xy, P, w), X, atol=1e-7)


@settings(max_examples=40, deadline=None)
@given(views(noise=2e-3))
def test_triangulation_agrees_with_weighted_least_squares(case):
    """With noisy views, the DLT is the weighted least-squares solution of its rows
    w (x P3 - P1) and w (y P3 - P2), with the homogeneous coordinate fixed to 1."""
    cams, _, xy, w = case
    P = np.stack([c.P for c in cams])  # (V, 3, 4)
    x, y = xy[..., 0, None], xy[..., 1, None]  # (A, B, V, 1)
    rows = np.concatenate([x * P[:, 2] - P[:, 0], y * P[:, 2] - P[:, 1]], axis=-2)
    rows = rows * np.concatenate([w, w], axis=-1)[..., None]  # (A, B, 2V, 4)
    ref = [
        np.linalg.lstsq(r[:, :3], -r[:, 3], rcond=None)[0]
        for r in rows.reshape(-1, 2 * len(cams), 4)
    ]
    ref = np.reshape(ref, (*xy.shape[:-2], 3))
    np.testing.assert_allclose(triangulate_dlt(xy, P, w), ref, atol=1e-9)


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
    with pytest.raises(ValueError, match=r"P must have shape \(3, 3, 4\)"):
        triangulate_dlt(np.zeros((5, 3, 2)), np.zeros((2, 3, 4)), np.ones((5, 3)))
    with pytest.raises(ValueError, match=r"xy must have shape"):
        triangulate_dlt(np.zeros((5, 3, 3)), np.zeros((3, 3, 4)), np.ones((5, 3)))


@settings(max_examples=30, deadline=None)
@given(rigs(2, 2), points(st.integers(1, 40)))
def test_fundamental_matrix_epipolar_constraint(pair, X):
    a, b = pair
    ua, ub = undistort_pixels(project(X, a), a), undistort_pixels(project(X, b), b)
    F = fundamental_matrix(a, b)
    assert symmetric_epipolar_distance(ua, ub, F).max() < 1e-6
    # a point moved 25 px off its epipolar line in b is measured in pixels: 25 px in b, so at
    # least half that on average over the two images
    line = homogeneous(ua) @ F.T  # (N, 3) lines of ua in camera b
    shifted = ub + 25.0 * line[:, :2] / np.linalg.norm(line[:, :2], axis=1, keepdims=True)
    assert symmetric_epipolar_distance(ua, shifted, F).min() > 12.5 - 1e-6


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
