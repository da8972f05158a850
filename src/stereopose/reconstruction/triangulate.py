"""Triangulation of grouped people: the reference `pair` mode, `weighted` and `robust`.

Every function works on all people of a frame at once. Arrays for G grouped people in a rig of
C cameras (a camera without a detection in the group has NaN coordinates and weight 0):
  xy: (G, 17, C, 2) ideal normalised coordinates; w: (G, 17, C) confidences (0 = unused);
  P: (C, 3, 4) [R | t]; focal: (C,) pixels; size_px: (G, C) person size in each image, pixels.
Each returns X (G, 17, 3) metres and used (G, 17, C) bool, the views each joint rests on.
"""

from __future__ import annotations

import numpy as np

from stereopose.geometry.camera import homogeneous, project_normalized
from stereopose.geometry.triangulation import triangulate_dlt
from stereopose.skeleton import LR_PAIRS

_LEFT = np.array([p[0] for p in LR_PAIRS])
_RIGHT = np.array([p[1] for p in LR_PAIRS])


def camera_pairs(C: int) -> tuple[np.ndarray, np.ndarray]:
    """All unordered camera pairs (a < b) as two (K,) index arrays."""
    a, b = np.triu_indices(C, k=1)
    return a, b


def reprojection_errors(X: np.ndarray, xy: np.ndarray, P: np.ndarray, focal: np.ndarray):
    """Pixel distance between X reprojected and the observations.

    X: (..., 3) broadcastable to xy's leading axes without the camera axis; xy: (..., C, 2).
    Returns (..., C) errors in pixels of the ideal image (NaN where either side is missing).
    """
    proj = project_normalized(X[..., None, :], P)
    return np.hypot(*np.moveaxis(proj - xy, -1, 0)) * focal


def triangulate_weighted(xy: np.ndarray, w: np.ndarray, P: np.ndarray):
    """Confidence-weighted DLT over every view of each person."""
    X = triangulate_dlt(xy, P, w)
    used = (w > 0) & np.isfinite(X).all(axis=-1, keepdims=True)
    return X, used


def triangulate_pair(
    xy: np.ndarray,
    w: np.ndarray,
    conf: np.ndarray,
    P: np.ndarray,
    E: np.ndarray,
    focal: np.ndarray,
    a: float,
    b: float,
    min_common_joints: int,
):
    """The reference method: per person, the camera pair (j, k) minimising
    a * mean_i d_i^{jk} - b * (mean_i conf_i^j + mean_i conf_i^k), then two-view DLT.

    conf: (G, 17, C) raw confidences (0 where no detection); d_i^{jk} is the symmetric epipolar
    distance of joint i in pixels, averaged over joints usable in both views; E: (C, C, 3, 3).
    """
    G, C = xy.shape[0], xy.shape[2]
    ka, kb = camera_pairs(C)
    xa, xb = np.nan_to_num(xy[:, :, ka]), np.nan_to_num(xy[:, :, kb])  # (G, J, K, 2)
    ha, hb = homogeneous(xa), homogeneous(xb)
    Ek = E[ka, kb]  # (K, 3, 3)
    lb = np.einsum("kij,gnkj->gnki", Ek, ha)
    la = np.einsum("kji,gnkj->gnki", Ek, hb)
    d_b = np.abs((lb * hb).sum(-1)) / np.hypot(lb[..., 0], lb[..., 1]) * focal[kb]
    d_a = np.abs((la * ha).sum(-1)) / np.hypot(la[..., 0], la[..., 1]) * focal[ka]
    both = (w[:, :, ka] > 0) & (w[:, :, kb] > 0)
    n = both.sum(axis=1)  # (G, K)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean_d = np.where(both, 0.5 * (d_a + d_b), 0.0).sum(axis=1) / n
    mean_conf = conf.mean(axis=1)  # (G, C)
    score = a * mean_d - b * (mean_conf[:, ka] + mean_conf[:, kb])
    score[(n < min_common_joints) | ~np.isfinite(score)] = np.inf
    best = np.argmin(score, axis=1)  # (G,)
    ok = np.isfinite(score[np.arange(G), best])
    sel = np.zeros((G, C), dtype=bool)
    sel[np.arange(G)[ok], ka[best[ok]]] = True
    sel[np.arange(G)[ok], kb[best[ok]]] = True
    w2 = np.where(sel[:, None, :] & (w > 0), 1.0, 0.0)
    return triangulate_weighted(xy, w2, P)


def triangulate_robust(
    xy: np.ndarray,
    w: np.ndarray,
    P: np.ndarray,
    focal: np.ndarray,
    size_px: np.ndarray,
    inlier_px: float,
    inlier_rel: float,
    fix_swaps: bool,
    iterations: int = 2,
):
    """Weighted DLT over the views that agree, with left/right swaps of the detector corrected.

    Per joint, every two-view solution is scored by the confidence of the views that reproject
    within the threshold max(inlier_px, inlier_rel * size_px); the best seeds the estimate. A
    left/right joint pair of a view that fits only when exchanged is exchanged. The final point
    is the weighted DLT over the inlier views, refined `iterations` times.
    Returns X, used, and xy, w with swapped labels corrected.
    """
    C = xy.shape[2]
    thr = np.maximum(inlier_px, inlier_rel * np.nan_to_num(size_px))[:, None, :]  # (G, 1, C)
    ka, kb = camera_pairs(C)
    sel = np.stack([ka, kb], axis=1)  # (K, 2)
    Xk = triangulate_dlt(xy[:, :, sel], P[sel], w[:, :, sel])  # (G, J, K, 3)
    err = reprojection_errors(Xk, xy[:, :, None], P, focal)  # (G, J, K, C)
    inl = (err < thr[:, :, None]) & (w[:, :, None] > 0)
    score = np.where(inl, w[:, :, None], 0.0).sum(-1)
    score -= 1e-3 * np.where(inl, err / thr[:, :, None], 0.0).sum(-1)  # tie-break: tighter fit
    score[~np.isfinite(Xk).all(-1)] = -np.inf
    best = np.argmax(score, axis=-1)  # (G, J)
    X = np.take_along_axis(Xk, best[..., None, None], axis=2)[:, :, 0]

    if fix_swaps:
        xy, w = _fix_swaps(X, xy, w, P, focal, thr)

    used = np.zeros(w.shape, dtype=bool)
    for _ in range(iterations):
        e = reprojection_errors(X, xy, P, focal)
        used = (e < thr) & (w > 0)
        X_new = triangulate_dlt(xy, P, np.where(used, w, 0.0))
        X = np.where(np.isfinite(X_new), X_new, X)
    e = reprojection_errors(X, xy, P, focal)
    used = (e < thr) & (w > 0)
    X = np.where((used.sum(-1) >= 2)[..., None], X, np.nan)
    used &= np.isfinite(X).all(-1, keepdims=True)
    return X, used, xy, w


def _fix_swaps(X, xy, w, P, focal, thr):
    """Exchange a view's left/right joints where only the exchanged labels fit X."""
    e_keep_l = reprojection_errors(X[:, _LEFT], xy[:, _LEFT], P, focal)  # (G, 8, C)
    e_keep_r = reprojection_errors(X[:, _RIGHT], xy[:, _RIGHT], P, focal)
    e_swap_l = reprojection_errors(X[:, _RIGHT], xy[:, _LEFT], P, focal)
    e_swap_r = reprojection_errors(X[:, _LEFT], xy[:, _RIGHT], P, focal)
    t = thr[:, 0][:, None, :]  # (G, 1, C)
    with np.errstate(invalid="ignore"):
        keep_fits = (e_keep_l < t) & (e_keep_r < t)
        swap_fits = (e_swap_l < t) & (e_swap_r < t)
        better = (e_swap_l + e_swap_r) < 0.5 * (e_keep_l + e_keep_r)
    swap = swap_fits & better & ~keep_fits & (w[:, _LEFT] > 0) & (w[:, _RIGHT] > 0)
    if not swap.any():
        return xy, w
    xy, w = xy.copy(), w.copy()
    s2 = swap[..., None]
    xl, xr = xy[:, _LEFT], xy[:, _RIGHT]
    wl, wr = w[:, _LEFT], w[:, _RIGHT]
    xy[:, _LEFT], xy[:, _RIGHT] = np.where(s2, xr, xl), np.where(s2, xl, xr)
    w[:, _LEFT], w[:, _RIGHT] = np.where(swap, wr, wl), np.where(swap, wl, wr)
    return xy, w
