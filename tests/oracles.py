"""NumPy reference forms of the compiled loops, which the tests check the loops against.

Each is the array formulation of what a compiled loop does joint by joint: written
independently of the loops, so an agreement between the two means something.
"""

from __future__ import annotations

import functools

import numpy as np

from stereopose.association.grouping import upper_pairs
from stereopose.reconstruction.labels import _HEAD_RADIUS_M, _HEAD_WIDTH_M


def project_to_cameras_numpy(points_world: np.ndarray, P: np.ndarray) -> np.ndarray:
    """Project (..., 3) world points into each of C cameras [R | t] (C, 3, 4) at once.

    Returns (..., C, 2) ideal normalised coordinates; NaN behind a camera or for NaN input.
    """
    C = P.shape[0]
    # one matmul for all cameras: X @ [R_0^T | R_1^T | ...] + [t_0 | t_1 | ...]
    R_all = P[:, :, :3].transpose(2, 0, 1).reshape(3, C * 3)
    Xc = (points_world @ R_all + P[:, :, 3].reshape(C * 3)).reshape(*points_world.shape[:-1], C, 3)
    z = Xc[..., 2:3]
    out = np.full((*Xc.shape[:-1], 2), np.nan)
    np.divide(Xc[..., :2], z, out=out, where=z > 1e-3)
    return out


def reprojection_errors_numpy(X, xy, P, focal):
    """(..., C) pixel distance between X (..., 3) reprojected and xy (..., C, 2)."""
    d = project_to_cameras_numpy(X, P) - xy
    return np.hypot(d[..., 0], d[..., 1]) * focal


# N[:3, :3] entries a b c d f g (upper triangle) and N[:3, 3], in a flattened 4 x 4
_ENTRIES = np.array([0, 1, 2, 5, 6, 10, 3, 7, 11])


def dlt_blocks(P: np.ndarray) -> np.ndarray:
    """(..., V, 3, 4) cameras -> (..., V * 4, 16) per-view blocks of A^T A.

    Each view adds the rows w (x P3 - P1) and w (y P3 - P2) to the DLT matrix A, so A^T A is a
    sum over views of w^2 [(x^2 + y^2) P3P3 - x (P1P3 + P3P1) - y (P2P3 + P3P2) + P1P1 + P2P2]:
    per-view coefficients times these four per-camera 4 x 4 blocks. They depend on the cameras
    only, so they can be computed once per rig.
    """
    P1, P2, P3 = P[..., 0, :], P[..., 1, :], P[..., 2, :]

    def outer(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        return a[..., :, None] * b[..., None, :]

    p13, p23 = outer(P1, P3), outer(P2, P3)
    blocks = np.stack(
        [
            outer(P3, P3),
            -(p13 + p13.swapaxes(-1, -2)),
            -(p23 + p23.swapaxes(-1, -2)),
            outer(P1, P1) + outer(P2, P2),
        ],
        axis=-3,
    )  # (..., V, 4, 4, 4)
    return blocks.reshape(*blocks.shape[:-4], blocks.shape[-4] * 4, 16)


def triangulate_dlt_numpy(
    xy: np.ndarray, P: np.ndarray | None, weights: np.ndarray, blocks: np.ndarray | None = None
) -> np.ndarray:
    """Weighted DLT triangulation.

    xy: (..., V, 2) normalised coordinates of one point seen in V views (NaN where unseen).
    P: (..., V, 3, 4) or (V, 3, 4) cameras [R | t], world -> camera.
    weights: (..., V) non-negative; a view with weight 0 or NaN coordinates is ignored.
    blocks: dlt_blocks(P), when already computed (P may then be None).
    Returns (..., 3) world points; NaN where fewer than 2 views have positive weight.
    """
    xy = np.asarray(xy, dtype=np.float64)
    if xy.ndim < 2 or xy.shape[-1] != 2:
        raise ValueError(f"xy must have shape (..., V, 2), got {xy.shape}")
    V = xy.shape[-2]
    if blocks is None:
        if P is None or P.shape[-3:] != (V, 3, 4):
            raise ValueError(f"P must have shape (..., {V}, 3, 4), got {np.shape(P)}")
        blocks = dlt_blocks(P)
    elif blocks.shape[-2:] != (V * 4, 16):
        raise ValueError(f"blocks must have shape (..., {V * 4}, 16), got {blocks.shape}")
    b = blocks
    seen = np.isfinite(xy[..., 0]) & np.isfinite(xy[..., 1])
    w = np.asarray(weights, dtype=np.float64)
    w2 = np.where(seen & (w > 0), w, 0.0) ** 2  # NaN or non-positive weight: view unused
    x = np.where(seen, xy[..., 0], 0.0)
    y = np.where(seen, xy[..., 1], 0.0)
    coef = np.empty((*w2.shape, 4))  # (..., V, 4) per-view coefficients of the blocks
    coef[..., 1] = w2 * x
    coef[..., 2] = w2 * y
    coef[..., 3] = w2
    coef[..., 0] = coef[..., 1] * x + coef[..., 2] * y
    c = coef.reshape(*coef.shape[:-2], V * 4)
    if b.ndim == 2:
        N = c @ b
    elif b.ndim == 3 and c.shape[-2] == b.shape[0]:
        # one block set per item of the last batch axis: a batched matmul over that axis
        flat = c.reshape(-1, *c.shape[-2:]).swapaxes(0, 1)  # (K, n, V * 4)
        N = np.matmul(flat, b).swapaxes(0, 1)
    else:
        N = np.einsum("...i,...ij->...j", c, b)
    # Least squares with the homogeneous coordinate fixed to 1: (A3^T A3) X = -A3^T a4; fewer
    # than two views leave it singular, which gives NaN.
    return _solve_normal_equations(N.reshape(*c.shape[:-1], 4, 4))


def _solve_normal_equations(N: np.ndarray) -> np.ndarray:
    """X (..., 3) minimising |A [X, 1]|^2 from N = A^T A (..., 4, 4): the symmetric 3 x 3
    system N[:3, :3] X = -N[:3, 3], solved by the adjugate; NaN where (near) singular."""
    e = N.reshape(*N.shape[:-2], 16)[..., _ENTRIES]
    a, b, c, d, f, g, r0, r1, r2 = np.moveaxis(e, -1, 0)  # M = [[a, b, c], [b, d, f], [c, f, g]]
    A, B, C = d * g - f * f, c * f - b * g, b * f - c * d  # adjugate, first row
    D, E, F = a * g - c * c, b * c - a * f, a * d - b * b
    det = a * A + b * B + c * C
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        inv = np.where(np.abs(det) > 1e-12 * np.abs(a + d + g) ** 3, -1.0 / det, np.nan)
    out = np.empty((*det.shape, 3))
    out[..., 0] = (A * r0 + B * r1 + C * r2) * inv
    out[..., 1] = (B * r0 + D * r1 + E * r2) * inv
    out[..., 2] = (C * r0 + E * r1 + F * r2) * inv
    return out


def select_views_numpy(xy, w, P, focal, thr, X_all, blocks=None, pair_blocks=None):
    """The NumPy form of reconstruction._kernels.select_views (same arguments and results)."""
    thr = thr[:, None, :]
    if blocks is None:
        blocks = dlt_blocks(P)
    err_all = reprojection_errors_numpy(X_all, xy, P, focal)
    err = err_all.copy()
    used = (w > 0) & (err < thr)
    # Joints where every view agrees are done; the others are re-seeded from the two-view
    # solution most views agree with, then solved again from the views that agree with it.
    # (with two views or fewer there is nothing to choose: the result would be X_all)
    seen = (w > 0).sum(-1)
    redo = (seen > 2) & ((used.sum(-1) < seen) | ~np.isfinite(X_all[..., 0]))  # (G, J)
    X = X_all.copy()
    if redo.any():
        xr, wr, tr = xy[redo], w[redo], np.broadcast_to(thr, w.shape)[redo]
        ur = _best_pair_inliers(xr, wr, P, focal, tr, pair_blocks)
        Xr = triangulate_dlt_numpy(xr, P, np.where(ur, wr, 0.0), blocks)
        er = reprojection_errors_numpy(Xr, xr, P, focal)
        X[redo], used[redo], err[redo] = Xr, ur & (er < 1.5 * tr), er
    # Where fewer than two views agree, the views cannot be told apart: all of them are used
    # (an occluded joint is better placed roughly than not at all; its confidence stays low).
    few = used.sum(-1) < 2
    if few.any():
        X[few], used[few], err[few] = X_all[few], w[few] > 0, err_all[few]
    return X, used, err


@functools.lru_cache(maxsize=32)
def pair_views(C: int) -> np.ndarray:
    """(K, 2) camera indices of every pair (a < b)."""
    return np.stack(upper_pairs(C), axis=1)


def _best_pair_inliers(xy, w, P, focal, thr, pair_blocks=None):
    """For n joints (n, C, 2), (n, C): the views (n, C) that agree with the two-view solution
    most views agree with (scored by their confidence)."""
    sel = pair_views(xy.shape[1])  # (K, 2)
    Xk = triangulate_dlt_numpy(
        xy[:, sel], None if pair_blocks is not None else P[sel], w[:, sel], pair_blocks
    )  # (n, K, 3)
    err = reprojection_errors_numpy(Xk, xy[:, None], P, focal)  # (n, K, C)
    t = thr[:, None]
    inl = (err < t) & (w[:, None] > 0)
    # confidence of the agreeing views; ties go to the tighter fit
    score = np.where(inl, w[:, None] - 1e-3 * err / t, 0.0).sum(-1)
    score[np.isnan(Xk[..., 0])] = -np.inf
    best = np.argmax(score, axis=-1)
    return inl[np.arange(len(best)), best]


def _lead_numpy(lead, right):
    """(G,) how far horizontal offsets lead (G, 2) reach ahead, ahead being up x right."""
    with np.errstate(invalid="ignore", divide="ignore"):
        return (lead[:, 1] * right[:, 0] - lead[:, 0] * right[:, 1]) / np.hypot(*right.T)


def body_orientation_numpy(X, face_margin_m: float = 0.03, thigh_margin_m: float = 0.05):
    """The NumPy form of reconstruction.labels.body_orientation: (flip_upper (G,),
    flip_legs (G,)) of X (G, 17, 3)."""
    ears = np.isfinite(X[:, [3, 4], 0]).all(1)
    hl, hr = np.where(ears, 3, 1), np.where(ears, 4, 2)
    g = np.arange(X.shape[0])
    mid = 0.5 * (X[g, hl] + X[g, hr])
    with np.errstate(invalid="ignore"):
        stray = (np.linalg.norm(X[:, 0] - mid, axis=-1) >= _HEAD_RADIUS_M) | (
            np.linalg.norm(X[g, hr] - X[g, hl], axis=-1) >= _HEAD_WIDTH_M
        )
    axes = np.stack([X[:, 6, :2] - X[:, 5, :2], X[:, 12, :2] - X[:, 11, :2]])  # (2, G, 2)
    known = np.isfinite(axes).all(-1, keepdims=True)
    right = np.where(known, axes, 0.0).sum(0)
    right[~known.any(0)[:, 0]] = np.nan
    seen = np.isfinite(X[:, :3, 0])
    seen[:, 0] &= ~stray
    with np.errstate(invalid="ignore", divide="ignore"):  # no face: NaN
        face = np.where(seen[..., None], X[:, :3, :2], 0.0).sum(1) / seen.sum(1, keepdims=True)
    shoulders = _lead_numpy(face - 0.5 * (X[:, 5, :2] + X[:, 6, :2]), right)
    nose = X[:, 0, :2] - mid[:, :2]
    head = _lead_numpy(nose, right)
    own = _lead_numpy(nose, X[g, hr, :2] - X[g, hl, :2])
    head = np.where(np.isfinite(head), head, own)
    head[stray] = np.nan
    leads = np.stack([shoulders, head])
    ahead = np.where(np.isfinite(leads), leads, 0.0).sum(0)  # a missing lead adds nothing
    flip_upper = ahead < -face_margin_m
    hips = np.where(flip_upper[:, None, None], X[:, [12, 11]], X[:, [11, 12]])
    d = hips[:, :, None] - X[:, None, [13, 14]]  # (G, hip, knee, 3)
    dist = np.sqrt(np.einsum("ghkx,ghkx->ghk", d, d))
    flip_legs = dist[:, 0, 1] + dist[:, 1, 0] < dist[:, 0, 0] + dist[:, 1, 1] - thigh_margin_m
    return flip_upper, flip_legs
