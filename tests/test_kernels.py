"""The compiled loops give what the NumPy formulations give."""

from __future__ import annotations

import numpy as np
import pytest

from stereopose.association.affinity import Detections
from stereopose.geometry.camera import project_to_cameras, undistort_normalized
from stereopose.geometry.triangulation import dlt_blocks, triangulate_dlt
from stereopose.kernels import claim_costs, dlt_all, select_views, undistort
from stereopose.reconstruction import Reconstructor
from stereopose.reconstruction.triangulate import (
    JOINT_PARTS,
    _body_orientation,
    body_orientation_numpy,
    pair_views,
    select_views_numpy,
)
from stereopose.sim import simulate
from stereopose.skeleton import SWAP


@pytest.fixture(scope="module")
def hard():
    return simulate(num_frames=40, seed=5, difficulty="hard")


def _groups(scene, t):
    """Frame t's detections gathered per true worker, as the triangulation receives them."""
    rec = Reconstructor(scene.rig)
    people = [scene.detections[t][n] for n in scene.rig.names]
    det = Detections.from_people(scene.rig, people, 0.3)
    owners = np.concatenate([scene.detection_truth[t][n] for n in scene.rig.names])
    groups = [np.flatnonzero(owners == w) for w in np.unique(owners[owners >= 0])]
    groups = [g for g in groups if g.size >= 2]
    xy, conf, size_px, _ = rec._gather(det, groups)
    return rec, xy, np.where(conf >= 0.05, conf, 0.0), size_px


def test_select_views_matches_numpy(hard):
    checked = 0
    for t in range(0, 40, 3):
        rec, xy, w, size_px = _groups(hard, t)
        if xy.shape[0] == 0:
            continue
        thr = np.fmax(10.0, 0.03 * size_px)
        X_all = dlt_all(xy, w, rec.P)
        pair_blocks = dlt_blocks(rec.P[pair_views(len(hard.rig))])
        got = select_views(xy, w, rec.P, rec.focal, thr, X_all)
        blocks = dlt_blocks(rec.P)
        ref = select_views_numpy(xy, w, rec.P, rec.focal, thr, X_all, blocks, pair_blocks)
        np.testing.assert_allclose(got[0], ref[0], rtol=0, atol=1e-9)
        np.testing.assert_array_equal(got[1], ref[1])
        np.testing.assert_allclose(got[2], ref[2], rtol=1e-9, atol=1e-9)
        checked += xy.shape[0]
    assert checked > 50


def test_dlt_matches_numpy(hard):
    rec, xy, w, _ = _groups(hard, 7)
    np.testing.assert_allclose(
        dlt_all(xy, w, rec.P), triangulate_dlt(xy, rec.P, w), rtol=0, atol=1e-9
    )


def test_body_orientation_matches_numpy(hard):
    rng = np.random.default_rng(0)
    X = hard.truth[hard.present].copy()
    X = np.concatenate([X, X[:, SWAP], X[:, [*range(13), 14, 13, 16, 15]]])
    stray = X.copy()  # noses and ears thrown off the head
    stray[:, [0, 3]] += rng.normal(0.0, 0.3, (stray.shape[0], 2, 3))
    X = np.concatenate([X, stray])
    X[rng.random(X.shape[:2]) < 0.2] = np.nan
    for got, ref in zip(_body_orientation(X), body_orientation_numpy(X), strict=True):
        np.testing.assert_array_equal(got, ref)


def test_undistort_matches_opencv(hard):
    rng = np.random.default_rng(1)
    fxy, dist, _ = hard.rig.lenses
    for c, cam in enumerate(hard.rig):
        uv = rng.uniform([0, 0], cam.size, (500, 2))
        uv[::50] = np.nan
        got = undistort(uv, np.full(500, c), fxy, dist, 1e-8, 30)
        np.testing.assert_allclose(got, undistort_normalized(uv, cam), rtol=0, atol=1e-12)


def test_claim_costs_match_numpy(hard):
    t = 11
    rec = Reconstructor(hard.rig)
    det = Detections.from_people(hard.rig, [hard.detections[t][n] for n in hard.rig.names], 0.3)
    predicted = hard.truth[t, hard.present[t]] + 0.02
    proj = project_to_cameras(predicted, rec.P)
    ok = det.conf >= 0.3
    best, part = claim_costs(det.xy, ok, det.size, det.camera, proj, SWAP, JOINT_PARTS, 4)
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
    from stereopose.association.affinity import epipolar_distances
    from stereopose.geometry.camera import homogeneous

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
    from stereopose.association.affinity import epipolar_costs, epipolar_distances

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
