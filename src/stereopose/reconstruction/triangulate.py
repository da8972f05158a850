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
from stereopose.skeleton import LR_PAIRS, SWAP

_LEFT = np.array([p[0] for p in LR_PAIRS])
_RIGHT = np.array([p[1] for p in LR_PAIRS])
# Detectors swap the whole body or the legs alone: labels are decided for these parts apart.
_PARTS = (
    np.array([i for i, (left, _) in enumerate(LR_PAIRS) if left < 13]),  # face, arms, hips
    np.array([i for i, (left, _) in enumerate(LR_PAIRS) if left >= 13]),  # knees, ankles
)
_MAX_LABEL_CAMERAS = 12  # 2^C labelings are enumerated


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
    E: np.ndarray | None = None,
    size: np.ndarray | None = None,
):
    """Weighted DLT over the views that agree, with left/right swaps of the detector corrected.

    A view agrees when it reprojects within max(inlier_px, inlier_rel * size_px). Joints where
    the weighted DLT over all views leaves a view outside are re-seeded: every two-view solution
    is scored by the confidence of the views that agree with it, and the best wins. A left/right
    joint pair of a view that fits only when exchanged is exchanged. The final point is the
    weighted DLT over the agreeing views (at least two). With E (C, C, 3, 3) and size (G, C)
    (person size in normalised units), the left/right labels of all views are first made
    consistent with each other (see _consistent_labels).
    Returns X, used, and xy, w with swapped labels corrected.
    """
    C = xy.shape[2]
    thr = np.maximum(inlier_px, inlier_rel * np.nan_to_num(size_px))[:, None, :]  # (G, 1, C)
    if fix_swaps and E is not None and C <= _MAX_LABEL_CAMERAS:
        xy, w = _consistent_labels(xy, w, E, size)
    X = triangulate_dlt(xy, P, w)
    if fix_swaps:
        flips = _body_orientation(X)
        if any(f.any() for f in flips):
            for part, flip in zip(_PARTS, flips, strict=True):
                xy, w = _exchange(xy, w, part, np.broadcast_to(flip[:, None], (len(flip), C)))
            X = triangulate_dlt(xy, P, w)
    err = reprojection_errors(X, xy, P, focal)
    with np.errstate(invalid="ignore"):
        outlier = (w > 0) & ~(err < thr)
    redo = outlier.any(-1) | ~np.isfinite(X).all(-1)  # (G, J)
    if redo.any():
        X[redo] = _best_pair_seed(xy[redo], w[redo], P, focal, np.broadcast_to(thr, w.shape)[redo])
    if fix_swaps:
        xy, w = _fix_swaps(X, xy, w, P, focal, thr)
    err = reprojection_errors(X, xy, P, focal)
    used = (err < thr) & (w > 0)
    X = triangulate_dlt(xy, P, np.where(used, w, 0.0))
    err = reprojection_errors(X, xy, P, focal)
    used &= err < 1.5 * thr
    X = np.where((used.sum(-1) >= 2)[..., None], X, np.nan)
    used &= np.isfinite(X).all(-1, keepdims=True)
    return X, used, xy, w


def _best_pair_seed(xy, w, P, focal, thr):
    """For n joints (n, C, 2), (n, C), the two-view solution most views agree with: (n, 3)."""
    C = xy.shape[1]
    ka, kb = camera_pairs(C)
    sel = np.stack([ka, kb], axis=1)  # (K, 2)
    Xk = triangulate_dlt(xy[:, sel], P[sel], w[:, sel])  # (n, K, 3)
    err = reprojection_errors(Xk, xy[:, None], P, focal)  # (n, K, C)
    t = thr[:, None]
    with np.errstate(invalid="ignore"):
        inl = (err < t) & (w[:, None] > 0)
    score = np.where(inl, w[:, None], 0.0).sum(-1)
    score -= 1e-3 * np.where(inl, err / t, 0.0).sum(-1)  # tie-break: the tighter fit
    score[~np.isfinite(Xk).all(-1)] = -np.inf
    best = np.argmax(score, axis=-1)
    return Xk[np.arange(len(best)), best]


def _labelings(C: int) -> np.ndarray:
    """(2^C, C) every assignment of 'swapped' (1) or 'as detected' (0) to C views."""
    return (np.arange(2**C)[:, None] >> np.arange(C)[None, :]) & 1


def _consistent_labels(xy, w, E, size):
    """Exchange left/right labels of views so that all views of a person agree.

    For every pair of views (a, b) and body part, the epipolar cost of matching left to left
    ("same") and left to right ("cross") is measured; the labeling of all views that minimises
    the total cost wins, and of a labeling and its mirror (equal cost) the one that exchanges
    fewer views. Epipolar costs ignore 3D, so this works before any triangulation.
    """
    G, _, C, _ = xy.shape
    ka, kb = camera_pairs(C)
    h = homogeneous(np.nan_to_num(xy))  # (G, J, C, 3)
    lines = np.matmul(h[:, :, ka, None, :], E[ka, kb].swapaxes(-1, -2))[..., 0, :]  # (G,J,K,3)
    hb = h[:, :, kb]
    with np.errstate(invalid="ignore", divide="ignore"):
        norm = np.hypot(lines[..., 0], lines[..., 1])
        s_b = size[:, kb][:, None]  # (G, 1, K)
        d_same = np.abs((lines * hb).sum(-1)) / norm / s_b
        d_cross = np.abs((lines * hb[:, SWAP]).sum(-1)) / norm / s_b  # (G, J, K)
    ok = w > 0
    ok_same = ok[:, :, ka] & ok[:, :, kb]
    ok_cross = ok[:, :, ka] & ok[:, SWAP][:, :, kb]
    Z = _labelings(C)
    rel = Z[:, ka] ^ Z[:, kb]  # (L, K): 1 where the pair's labels differ
    out_xy, out_w = xy, w
    for part in _PARTS:
        joints = np.concatenate([_LEFT[part], _RIGHT[part]])
        both = ok_same[:, joints] & ok_cross[:, joints]
        same = np.where(both, np.nan_to_num(d_same[:, joints]), 0.0).sum(1)  # (G, K)
        cross = np.where(both, np.nan_to_num(d_cross[:, joints]), 0.0).sum(1)
        cost = same @ (1 - rel).T + cross @ rel.T  # (G, L)
        present = ok[:, joints].any(1)  # (G, C)
        cost += 1e-6 * (present.astype(float) @ Z.T)  # fewer exchanged views on ties
        swap = Z[np.argmin(cost, axis=1)].astype(bool) & present  # (G, C)
        if not swap.any():
            continue
        out_xy, out_w = _exchange(out_xy, out_w, part, swap)
    return out_xy, out_w


def _exchange(xy, w, part, swap):
    """Copies of xy (G, J, C, 2), w (G, J, C) with the left/right joints of `part` (indices
    into LR_PAIRS) exchanged where swap (G, C) is true."""
    if not swap.any():
        return xy, w
    xy, w = xy.copy(), w.copy()
    sl, sr = _LEFT[part], _RIGHT[part]
    m = swap[:, None, :]
    xl, xr, wl, wr = xy[:, sl], xy[:, sr], w[:, sl], w[:, sr]
    xy[:, sl] = np.where(m[..., None], xr, xl)
    xy[:, sr] = np.where(m[..., None], xl, xr)
    w[:, sl] = np.where(m, wr, wl)
    w[:, sr] = np.where(m, wl, wr)
    return xy, w


def _body_orientation(X, face_margin_m: float = 0.03, thigh_margin_m: float = 0.05):
    """Which people's labels are mirrored as a whole, from the body's handedness in 3D.

    Views alone cannot tell a labeling from its mirror when as many views are swapped as not.
    In 3D they can: with z up, the face lies in front of the shoulders, where front is
    up x (right shoulder - left shoulder); and each knee is nearer its own hip. X: (G, 17, 3).
    Returns (flip_upper (G,), flip_legs (G,)).
    """
    right = X[:, 6] - X[:, 5]
    front = np.stack([-right[:, 1], right[:, 0]], axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        front /= np.linalg.norm(front, axis=-1, keepdims=True)
        seen = np.isfinite(X[:, :3, :2])
        face = np.where(seen, X[:, :3, :2], 0.0).sum(1) / seen.sum(1)
        ahead = ((face - 0.5 * (X[:, 5, :2] + X[:, 6, :2])) * front).sum(-1)
    flip_upper = ahead < -face_margin_m
    hips = np.where(flip_upper[:, None, None], X[:, [12, 11]], X[:, [11, 12]])
    straight = np.linalg.norm(hips - X[:, [13, 14]], axis=-1).sum(-1)
    crossed = np.linalg.norm(hips - X[:, [14, 13]], axis=-1).sum(-1)
    with np.errstate(invalid="ignore"):
        flip_legs = crossed < straight - thigh_margin_m
    return flip_upper, flip_legs


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
