"""Triangulation of grouped people: the reference `pair` mode, `weighted` and `robust`.

Every function works on all people of a frame at once. Arrays for G grouped people in a rig of
C cameras (a camera without a detection in the group has NaN coordinates and weight 0):
  xy: (G, 17, C, 2) ideal normalised coordinates; w: (G, 17, C) confidences (0 = unused);
  P: (C, 3, 4) [R | t]; focal: (C,) pixels; size_px: (G, C) person size in each image, pixels.
Each returns X (G, 17, 3) metres and used (G, 17, C) bool, the views each joint rests on.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from stereopose.arrays import checked
from stereopose.association.grouping import upper_pairs
from stereopose.geometry.camera import homogeneous, project_to_cameras
from stereopose.geometry.epipolar import point_line_distance
from stereopose.geometry.triangulation import triangulate_dlt
from stereopose.reconstruction._kernels import (
    implausibility,
    place_single_views,
    select_views,
)
from stereopose.reconstruction.labels import (
    body_orientation,
    consistent_labels,
    exchange,
    exchange_joints,
    mirrored_pairs,
)
from stereopose.skeleton import JOINT_INDEX, JOINT_PARTS, LR_PAIRS, PART_OF_PAIR, SWAP, joint_table

_MAX_LABEL_CAMERAS = 12  # 2^C labelings are enumerated


def reprojection_errors(
    X: np.ndarray, xy: np.ndarray, P: np.ndarray, focal: np.ndarray
) -> np.ndarray:
    """Pixel distance between X reprojected and the observations.

    X: (..., 3) broadcastable to xy's leading axes without the camera axis; xy: (..., C, 2);
    P: (C, 3, 4). Returns (..., C) errors in pixels of the ideal image (NaN where either side
    is missing).
    """
    d = project_to_cameras(X, P) - xy
    return np.hypot(d[..., 0], d[..., 1]) * focal


def triangulate_weighted(
    xy: np.ndarray, w: np.ndarray, P: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Confidence-weighted DLT over every view of each person."""
    X = triangulate_dlt(xy, P, w)
    used = (w > 0) & np.isfinite(X).all(axis=-1, keepdims=True)
    return X, used


@dataclass(frozen=True)
class PairScore:
    """How triangulate_pair scores a camera pair: a * mean epipolar distance (pixels) - b *
    the views' mean confidences; a pair needs min_common_joints joints seen in both views."""

    a: float
    b: float
    min_common_joints: int


@dataclass(frozen=True)
class Robust:
    """triangulate_robust's settings: a view agrees when it reprojects within
    max(inlier_px, inlier_rel * the person's size in pixels); fix_swaps: the detector's
    left/right swaps corrected; relabel: then implausible skeletons solved again with
    labels exchanged (see _relabel_implausible)."""

    inlier_px: float
    inlier_rel: float
    fix_swaps: bool
    relabel: bool = True


def triangulate_pair(
    xy: np.ndarray,
    w: np.ndarray,
    conf: np.ndarray,
    P: np.ndarray,
    E: np.ndarray,
    focal: np.ndarray,
    score_by: PairScore,
) -> tuple[np.ndarray, np.ndarray]:
    """The reference method: per person, the camera pair (j, k) minimising
    a * mean_i d_i^{jk} - b * (mean_i conf_i^j + mean_i conf_i^k), then two-view DLT.

    conf: (G, 17, C) raw confidences (0 where no detection); d_i^{jk} is the symmetric epipolar
    distance of joint i in pixels, averaged over joints usable in both views; E: (C, C, 3, 3).
    """
    a, b, min_common_joints = score_by.a, score_by.b, score_by.min_common_joints
    G, C = xy.shape[0], xy.shape[2]
    ka, kb = upper_pairs(C)
    xa, xb = np.nan_to_num(xy[:, :, ka]), np.nan_to_num(xy[:, :, kb])  # (G, J, K, 2)
    ha, hb = homogeneous(xa), homogeneous(xb)
    Ek = E[ka, kb]  # (K, 3, 3)
    lb = np.einsum("kij,gnkj->gnki", Ek, ha)
    la = np.einsum("kji,gnkj->gnki", Ek, hb)
    both = (w[:, :, ka] > 0) & (w[:, :, kb] > 0)
    n = both.sum(axis=1)  # (G, K)
    with np.errstate(invalid="ignore", divide="ignore"):
        d_b = point_line_distance(xb, lb) * focal[kb]
        d_a = point_line_distance(xa, la) * focal[ka]
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
    robust: Robust,
    pair_distances: tuple[np.ndarray, np.ndarray] | None = None,
    rays: tuple[np.ndarray, np.ndarray] | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
    """Weighted DLT over the views that agree, with left/right swaps of the detector corrected.

    A view agrees when it reprojects within max(inlier_px, inlier_rel * size_px). Joints where
    the weighted DLT over all views leaves a view outside are re-seeded: every two-view solution
    is scored by the confidence of the views that agree with it, and the best wins. The final
    point is the weighted DLT over the agreeing views (at least two). With pair_distances
    (same, cross), each (G, 17, K) per-joint epipolar distances of the views of camera pairs
    (a < b), the left/right labels of all views are first made consistent.
    rays: (centers (C, 3), R (C, 3, 3)) of the cameras, to place joints seen in one view (see
    complete_single_views); then a joint whose two views disagree, one of them much weaker
    (an occluded or misplaced joint is reported faintly), rests on the stronger view alone.
    relabel: a skeleton whose left and right limbs differ in length is solved again with the
    labels of each view and body part exchanged in turn (see _relabel_implausible).
    Returns X, used, xy and w with swapped labels corrected, the reprojection errors
    (G, 17, C) in pixels of the views used (NaN elsewhere), and (G, 17) the joints placed
    from one view (None without rays).
    """
    C, fix_swaps = xy.shape[2], robust.fix_swaps
    # (G, 1, C); a NaN size: inlier_px
    thr = np.fmax(robust.inlier_px, robust.inlier_rel * size_px)[:, None, :]
    if fix_swaps and pair_distances is not None and C <= _MAX_LABEL_CAMERAS:
        xy, w = consistent_labels(xy, w, *pair_distances)
    X_all = triangulate_dlt(xy, P, w)
    if fix_swaps:
        flips = body_orientation(X_all)
        if flips[0].any() or flips[1].any():
            flip = np.stack(flips, axis=1)[:, PART_OF_PAIR]  # (G, 8)
            xy, w = exchange(xy, w, np.broadcast_to(flip[..., None], (*flip.shape, C)))
            # exchanging a part in every view exchanges its triangulated points
            X_all = exchange_joints(X_all, flip)
    X, used, err = choose_views(xy, w, P, focal, thr[:, 0], X_all)
    if fix_swaps and robust.relabel:
        X, used, xy, w, err = _relabel_implausible((X, used, xy, w, err), P, focal, size_px, robust)
    if fix_swaps:
        # The joints re-seeded above may settle on labels the whole-body check could not see
        # (a limb swapped in as many views as not); the final skeleton is checked once more.
        swap = mirrored_pairs(X)
        if swap.any():
            xy, w = exchange(xy, w, np.broadcast_to(swap[..., None], (*swap.shape, C)))
            X, used, err = (exchange_joints(a, swap) for a in (X, used, err))
    single = None
    if rays is not None:
        # two views that disagree, one far fainter than the other: the faint one is dropped
        two = (used.sum(-1) == 2) & (np.where(used, err, 0.0) > thr).any(-1)
        if two.any():
            w_max = np.where(used, w, 0.0).max(-1)
            w_min = np.where(used, w, np.inf).min(-1)
            faint = two & (w_min < 0.5 * w_max)
            if faint.any():
                X[faint] = np.nan
                used[faint] = False
                w = w.copy()
                w[faint] = np.where(w[faint] < w[faint].max(-1, keepdims=True), 0.0, w[faint])
        X, single = complete_single_views(X, used, xy, w, *rays)
        if single.any():
            err[single] = reprojection_errors(X[single], xy[single], P, focal)
    used &= np.isfinite(X[..., :1])
    return X, used, xy, w, np.where(used, err, np.nan), single


# Left and right bones compared by _implausibility: upper arms, forearms, thighs, shins, trunk
# sides.
_BONES_L = joint_table(
    ("left_shoulder", "left_elbow"),
    ("left_elbow", "left_wrist"),
    ("left_hip", "left_knee"),
    ("left_knee", "left_ankle"),
    ("left_shoulder", "left_hip"),
)
_BONES_R = SWAP[_BONES_L]
# Bones no adult's reach (a tall adult's length with a wide margin, m): shoulder and hip
# widths, then the limbs and trunk sides of _BONES_L and _BONES_R. A joint triangulated from
# views whose labels disagree lands far from the body, making some bone far too long.
_BONES_MAX = np.concatenate(
    [
        joint_table(("left_shoulder", "right_shoulder"), ("left_hip", "right_hip")),
        _BONES_L,
        _BONES_R,
    ]
)
_MAX_M = np.array([0.7, 0.55, *([0.5, 0.42, 0.65, 0.65, 0.85] * 2)])


def _implausibility(X: np.ndarray) -> np.ndarray:
    """(G,) 0 for a symmetric skeleton within adult proportions; grows with the difference of
    left and right bones (the sum of |left - right| over the sum of their means) and with each
    bone's excess over _MAX_M (as a fraction of it)."""
    return implausibility(np.ascontiguousarray(X), _BONES_L, _BONES_R, _BONES_MAX, _MAX_M)


def _relabel_implausible(
    solved: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray],
    P: np.ndarray,
    focal: np.ndarray,
    size_px: np.ndarray,
    robust: Robust,
    max_implausibility: float = 0.15,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Solve again the people whose skeleton is implausible by more than max_implausibility;
    solved: triangulate_robust's (X, used, xy, w, err), returned with them solved again.

    When a person's left/right offset runs along the epipolar lines of two views, the labels
    of one view can be exchanged and the views still agree: the skeleton is then wrong but
    consistent, with left and right limbs of different lengths, or bones (shoulders, hips)
    longer than any adult's (see _implausibility). For such people every view and body part
    (upper body, legs) is exchanged in turn, and the most plausible skeleton is kept if it is
    clearly better.
    """
    X, used, xy, w, err = solved
    asym = _implausibility(X)
    bad = np.flatnonzero(asym > max_implausibility)
    if bad.size == 0:
        return X, used, xy, w, err
    C = xy.shape[2]
    # candidates: (person, view, part) where the view sees that part
    present = np.einsum("gjc,jp->gpc", (w[bad] > 0).astype(np.float64), JOINT_PARTS) > 0
    g, part, view = np.nonzero(present)
    if g.size == 0:
        return X, used, xy, w, err
    swap = np.zeros((g.size, len(LR_PAIRS), C), dtype=bool)
    swap[np.arange(g.size), :, view] = PART_OF_PAIR[None, :] == part[:, None]
    cx, cw = exchange(xy[bad][g], w[bad][g], swap)
    Xc, uc, xc, wc, ec, _ = triangulate_robust(
        cx,
        cw,
        P,
        focal,
        size_px[bad][g],
        dataclasses.replace(robust, fix_swaps=True, relabel=False),
    )
    ac = _implausibility(Xc)
    ac[~np.isfinite(ac)] = np.inf
    X, used, xy, w, err = X.copy(), used.copy(), xy.copy(), w.copy(), err.copy()
    for i, person in enumerate(bad):
        mine = np.flatnonzero(g == i)
        if mine.size == 0:
            continue
        k = mine[np.argmin(ac[mine])]
        # clearly more symmetric, and in front of the cameras it rests on (a point behind
        # one reprojects to NaN)
        if ac[k] < 0.5 * asym[person] and not np.isnan(ec[k][uc[k]]).any():
            X[person], used[person], xy[person], w[person] = Xc[k], uc[k], xc[k], wc[k]
            err[person] = np.where(uc[k], ec[k], np.nan)
    return X, used, xy, w, err


# Per joint, its neighbours in the skeleton in order of preference: a joint seen in one view
# is placed at the depth of the first of them that is reconstructed (the parent first).
_ANCHORS: dict[str, tuple[str, ...]] = {
    "nose": ("left_eye", "right_eye", "left_ear", "right_ear", "left_shoulder", "right_shoulder"),
    "left_eye": ("nose", "right_eye", "left_ear"),
    "right_eye": ("nose", "left_eye", "right_ear"),
    "left_ear": ("left_eye", "nose", "left_shoulder"),
    "right_ear": ("right_eye", "nose", "right_shoulder"),
    "left_shoulder": ("right_shoulder", "left_hip", "left_elbow"),
    "right_shoulder": ("left_shoulder", "right_hip", "right_elbow"),
    "left_elbow": ("left_shoulder", "left_wrist"),
    "right_elbow": ("right_shoulder", "right_wrist"),
    "left_wrist": ("left_elbow",),
    "right_wrist": ("right_elbow",),
    "left_hip": ("right_hip", "left_shoulder", "left_knee"),
    "right_hip": ("left_hip", "right_shoulder", "right_knee"),
    "left_knee": ("left_hip", "left_ankle"),
    "right_knee": ("right_hip", "right_ankle"),
    "left_ankle": ("left_knee",),
    "right_ankle": ("right_knee",),
}
_ANCHOR_TABLE = np.full((len(SWAP), max(map(len, _ANCHORS.values()))), -1, dtype=np.int64)
for _name, _row in _ANCHORS.items():
    _ANCHOR_TABLE[JOINT_INDEX[_name], : len(_row)] = [JOINT_INDEX[a] for a in _row]


def complete_single_views(
    X: np.ndarray,
    used: np.ndarray,
    xy: np.ndarray,
    w: np.ndarray,
    centers: np.ndarray,
    rays_R: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Place joints seen in one view only (NaN in X) on that view's ray.

    X: (G, 17, 3); used: (G, 17, C) updated in place with the view used; xy: (G, 17, C, 2)
    ideal normalised coordinates; w: (G, 17, C) view weights; centers: (C, 3) camera centres;
    rays_R: (C, 3, 3) camera rotations R (world -> camera). One view gives a ray but no depth:
    the point taken is the ray's nearest to a reconstructed neighbouring joint (see _ANCHORS),
    which lies within one bone length of the true joint whatever the true depth. The view with
    the highest weight is taken. Joints are placed the parents first, so a wrist can hang from
    an elbow placed this way. Returns X with the joints placed and (G, 17) which ones were.
    """
    X = np.array(X, dtype=np.float64)  # a contiguous copy, placed in
    placed = place_single_views(X, used, xy, w, centers, rays_R, _ANCHOR_TABLE)
    return X, placed


def choose_views(
    xy: np.ndarray,
    w: np.ndarray,
    P: np.ndarray,
    focal: np.ndarray,
    thr: np.ndarray,
    X_all: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per joint, the views that agree and the point they give.

    xy: (G, J, C, 2) ideal normalised coordinates; w: (G, J, C) weights (0: unused); P:
    (C, 3, 4); focal: (C,) pixels; thr: (G, C) agreement threshold in pixels; X_all: (G, J, 3)
    the weighted DLT over all views. Where every view of a joint agrees with X_all (or it has
    two views or fewer), X_all stands. Otherwise every two-view solution is scored by the
    confidence of the views agreeing with it (ties to the tighter fit), and the point is the
    weighted DLT over the best one's agreeing views, kept where within 1.5 thr of it; with
    fewer than two kept, all views and X_all. Returns X (G, J, 3), used (G, J, C) and the
    errors of every view (G, J, C) in pixels.
    """
    n: dict[str, int] = {}
    return select_views(
        checked(xy, "xy", ("G", "J", "C", 2), sizes=n),
        checked(w, "w", ("G", "J", "C"), sizes=n),
        checked(P, "P", ("C", 3, 4), sizes=n),
        checked(focal, "focal", ("C",), sizes=n),
        checked(thr, "thr", ("G", "C"), sizes=n),
        checked(X_all, "X_all", ("G", "J", 3), sizes=n),
    )
