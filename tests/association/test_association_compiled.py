"""The compiled loops of the association (epipolar distances and costs, detection sizes,
costs against expected poses) give what their NumPy forms give, through the public wrappers."""

from __future__ import annotations

import numpy as np
import pytest

from stereopose.association.affinity import Detections, epipolar_costs, epipolar_distances
from stereopose.association.claims import pose_costs
from stereopose.geometry.camera import homogeneous, project_to_cameras
from stereopose.reconstruction import Reconstructor
from stereopose.sim import simulate
from stereopose.skeleton import JOINT_PARTS, SWAP


@pytest.fixture(scope="module")
def hard():
    return simulate(num_frames=40, seed=5, difficulty="hard")


def test_pose_costs_match_numpy(hard):
    t = 11
    rec = Reconstructor(hard.rig)
    det = Detections.from_people(hard.rig, [hard.detections[t][n] for n in hard.rig.names], 0.3)
    predicted = hard.truth[t, hard.present[t]] + 0.02
    proj = project_to_cameras(predicted, rec.P)
    ok = det.conf >= 0.3
    best, part = pose_costs(det, predicted, rec.P, 0.3, 4)
    mine = proj[:, :, det.camera].transpose(2, 0, 1, 3)
    ref_best = np.full(best.shape, np.inf)
    for lab, (xy, okj) in enumerate(((det.xy, ok), (det.xy[:, SWAP], ok[:, SWAP]))):
        d = np.linalg.norm(xy[:, None] - mine, axis=-1)
        have = okj[:, None] & np.isfinite(d)
        n = have.sum(-1)
        dd = np.where(have, d, 0.0)
        with np.errstate(invalid="ignore", divide="ignore"):
            c = dd.sum(-1) / (n * det.size[:, None])
            np.testing.assert_allclose(part[lab], (dd @ JOINT_PARTS) / (have @ JOINT_PARTS))
        c[(n < 4) | ~np.isfinite(c)] = np.inf
        ref_best = np.minimum(ref_best, c)
    np.testing.assert_allclose(best, ref_best)
    assert np.isfinite(best).sum() > 10


def test_epipolar_distances_match_numpy(hard):
    t = 9
    rec = Reconstructor(hard.rig)
    det = Detections.from_people(hard.rig, [hard.detections[t][n] for n in hard.rig.names], 0.3)
    dist = epipolar_distances(det, rec.E)
    n, m = dist.first, dist.second
    h = homogeneous(np.where(np.isfinite(det.xy), det.xy, 0.0))
    ca, cb = det.camera[n], det.camera[m]
    lines_m = np.matmul(h[n], rec.E[ca, cb].swapaxes(-1, -2))
    lines_n = np.matmul(h[m], rec.E[cb, ca].swapaxes(-1, -2))
    w_m = 0.5 / np.hypot(lines_m[..., 0], lines_m[..., 1]) / det.size[m][:, None]
    w_n = 0.5 / np.hypot(lines_n[..., 0], lines_n[..., 1]) / det.size[n][:, None]
    same = np.abs(np.einsum("mjk,mjk->mj", lines_m, h[m])) * (w_m + w_n)
    cross = np.abs(np.einsum("mjk,mjk->mj", lines_m, h[m][:, SWAP])) * (w_m + w_n[:, SWAP])
    assert n.size > 100
    np.testing.assert_allclose(dist.same, same, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(dist.cross, cross, rtol=1e-10, atol=1e-12)


def test_pair_costs_and_boxes_match_numpy(hard):
    t = 13
    rec = Reconstructor(hard.rig)
    det = Detections.from_people(hard.rig, [hard.detections[t][n] for n in hard.rig.names], 0.3)
    dist = epipolar_distances(det, rec.E)
    cost = epipolar_costs(det, dist, 0.3, 4)
    ok = det.conf >= 0.3
    ref = np.full(cost.shape, np.inf)
    best = np.full(dist.first.size, np.inf)
    for d, ok_m in ((dist.same, ok[dist.second]), (dist.cross, ok[dist.second][:, SWAP])):
        both = ok[dist.first] & ok_m
        k = both.sum(-1)
        with np.errstate(invalid="ignore", divide="ignore"):
            c = np.where(both, d, 0.0).sum(-1) / k
        c[(k < 4) | ~np.isfinite(c)] = np.inf
        best = np.minimum(best, c)
    ref[dist.first, dist.second] = ref[dist.second, dist.first] = best
    np.testing.assert_allclose(cost, ref, rtol=1e-12)
    assert np.isfinite(cost).sum() > 20
    # box diagonals of the confident joints
    lo = np.where(ok[..., None], det.xy, np.inf).min(1)
    hi = np.where(ok[..., None], det.xy, -np.inf).max(1)
    want = np.where(ok.sum(1) >= 2, np.hypot(*(hi - lo).T), np.nan)
    np.testing.assert_allclose(det.size, want, rtol=1e-12)
