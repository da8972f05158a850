"""The compiled loops of the robust triangulation give what their NumPy forms give, through
the public wrappers."""

from __future__ import annotations

import numpy as np
import pytest

from oracles import body_orientation_numpy, select_views_numpy
from stereopose.association.affinity import Detections
from stereopose.geometry.triangulation import triangulate_dlt
from stereopose.reconstruction import Reconstructor
from stereopose.reconstruction.labels import body_orientation
from stereopose.reconstruction.triangulate import choose_views
from stereopose.sim import simulate
from stereopose.skeleton import LEFT_ANKLE, LEFT_EAR, LEFT_KNEE, NOSE, SWAP


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


def test_choose_views_matches_numpy(hard):
    checked = redone = 0
    for t in range(0, 40, 3):
        rec, xy, w, size_px = _groups(hard, t)
        if xy.shape[0] == 0:
            continue
        thr = np.fmax(10.0, 0.03 * size_px)
        X_all = triangulate_dlt(xy, rec.P, w)
        got = choose_views(xy, w, rec.P, rec.focal, thr, X_all)
        ref = select_views_numpy(xy, w, rec.P, rec.focal, thr, X_all)
        np.testing.assert_allclose(got[0], ref[0], rtol=0, atol=1e-9)
        np.testing.assert_array_equal(got[1], ref[1])
        np.testing.assert_allclose(got[2], ref[2], rtol=1e-9, atol=1e-9)
        checked += xy.shape[0]
        redone += int((np.abs(got[0] - X_all) > 1e-9).any(-1).sum())
    assert checked > 50 and redone > 10  # the re-seeding path was taken too


def test_choose_views_names_a_wrong_shape(hard):
    rec, xy, w, size_px = _groups(hard, 3)
    thr = np.fmax(10.0, 0.03 * size_px)
    X_all = triangulate_dlt(xy, rec.P, w)
    with pytest.raises(ValueError, match=r"thr must have shape \(G, C\), got"):
        choose_views(xy, w, rec.P, rec.focal, thr[:, :-1], X_all)
    with pytest.raises(ValueError, match=r"w must have shape \(G, J, C\)"):
        choose_views(xy, w[..., 0], rec.P, rec.focal, thr, X_all)


def test_body_orientation_matches_numpy(hard):
    rng = np.random.default_rng(0)
    X = hard.truth[hard.present].copy()
    legs = np.arange(len(SWAP))
    legs[LEFT_KNEE:] = SWAP[LEFT_KNEE:]  # knees and ankles exchanged alone
    assert LEFT_ANKLE > LEFT_KNEE
    X = np.concatenate([X, X[:, SWAP], X[:, legs]])
    stray = X.copy()  # noses and ears thrown off the head
    stray[:, [NOSE, LEFT_EAR]] += rng.normal(0.0, 0.3, (stray.shape[0], 2, 3))
    X = np.concatenate([X, stray])
    X[rng.random(X.shape[:2]) < 0.2] = np.nan
    got, ref = body_orientation(X), body_orientation_numpy(X)
    for a, b in zip(got, ref, strict=True):
        np.testing.assert_array_equal(a, b)
    assert got[0].any() and got[1].any() and not got[0].all()


def test_with_many_views_the_pairs_come_from_the_most_confident_and_agree_with_all_pairs():
    import dataclasses

    from stereopose.reconstruction._kernels import MAX_SEEDS
    from stereopose.sim.scene import make_rig
    from stereopose.types import Rig

    cams = [*make_rig(12, np.random.default_rng(1)), *make_rig(12, np.random.default_rng(2))]
    rig = Rig([dataclasses.replace(c, name=f"v{i:02d}") for i, c in enumerate(cams)])
    rec = Reconstructor(rig)
    C = len(rig.names)
    assert C > MAX_SEEDS
    X0 = np.array([6.0, 4.0, 1.2, 1.0])
    uvw = np.einsum("cij,j->ci", rec.P, X0)
    xy = (uvw[:, :2] / uvw[:, 2:])[None, None].copy()  # (1, 1, C, 2)
    w = np.full((1, 1, C), 0.9)
    bad = np.arange(C) % 4 == 3  # a quarter of the views wrong, and less confident
    xy[0, 0, bad] += 80.0 / rec.focal[bad, None]
    w[0, 0, bad] = 0.4
    thr = np.full((1, C), 10.0)
    X_all = triangulate_dlt(xy, rec.P, w)
    got = choose_views(xy, w, rec.P, rec.focal, thr, X_all)
    ref = select_views_numpy(xy, w, rec.P, rec.focal, thr, X_all)
    np.testing.assert_allclose(got[0], ref[0], atol=1e-9)
    np.testing.assert_array_equal(got[1], ref[1])
    np.testing.assert_array_equal(got[1][0, 0], ~bad)  # the wrong views left out
    np.testing.assert_allclose(got[0][0, 0], X0[:3], atol=1e-6)
