"""The compiled geometry (projection, DLT, undistortion) agrees with its NumPy and OpenCV forms,
through the public wrappers."""

from __future__ import annotations

import numpy as np
import pytest

from oracles import project_to_cameras_numpy, triangulate_dlt_numpy
from stereopose.association.affinity import Detections
from stereopose.geometry.camera import project_to_cameras, undistort_normalized
from stereopose.geometry.triangulation import triangulate_dlt
from stereopose.sim import simulate
from stereopose.types import People2D


@pytest.fixture(scope="module")
def hard():
    return simulate(num_frames=10, seed=5, difficulty="hard")


def test_projection_matches_numpy(hard):
    rng = np.random.default_rng(0)
    P = np.stack([c.P for c in hard.rig])
    X = rng.uniform([-3, -3, -1], [8, 8, 3], (4, 17, 3))
    X[0, :3] = np.nan
    got = project_to_cameras(X, P)
    assert got.shape == (4, 17, len(hard.rig), 2)
    np.testing.assert_allclose(got, project_to_cameras_numpy(X, P), rtol=1e-12, atol=1e-12)
    assert np.isnan(got[0, :3]).all() and np.isfinite(got).any()


def test_dlt_matches_numpy(hard):
    rng = np.random.default_rng(1)
    P = np.stack([c.P for c in hard.rig])
    X = hard.truth[3, hard.present[3]]
    xy = project_to_cameras(X, P) + rng.normal(0, 2e-3, (*X.shape[:2], len(hard.rig), 2))
    w = rng.uniform(0.0, 1.0, xy.shape[:-1])
    w[w < 0.3] = 0.0  # views left out
    got = triangulate_dlt(xy, P, w)
    np.testing.assert_allclose(got, triangulate_dlt_numpy(xy, P, w), rtol=0, atol=1e-9)
    assert np.isfinite(got).sum() > 30


def test_wrappers_name_the_wrong_shape():
    with pytest.raises(ValueError, match=r"P must have shape \(C, 3, 4\), got \(3, 4\)"):
        project_to_cameras(np.zeros((2, 3)), np.zeros((3, 4)))
    with pytest.raises(ValueError, match=r"weights must have shape \(5, 3\), got \(5,\)"):
        triangulate_dlt(np.zeros((5, 3, 2)), np.zeros((3, 3, 4)), np.ones(5))


def test_undistortion_matches_opencv(hard):
    """Detections are undistorted by the compiled loop: OpenCV's undistortPoints, to 1e-12."""
    rng = np.random.default_rng(1)
    people = []
    for cam in hard.rig:
        kp = np.concatenate([rng.uniform([0, 0], cam.size, (30, 17, 2)), np.ones((30, 17, 1))], -1)
        kp[::7, ::5, :2] = np.nan
        people.append(People2D(camera=cam.name, frame=0, keypoints=kp))
    det = Detections.from_people(hard.rig, people, 0.3)
    for c, cam in enumerate(hard.rig):
        mine = det.camera == c
        want = undistort_normalized(det.pixels[mine], cam)
        np.testing.assert_allclose(det.xy[mine], want, rtol=0, atol=1e-12)
