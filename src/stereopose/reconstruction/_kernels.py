"""Compiled loops of the robust triangulation (numba): the choice of views, handedness and
limb checks, plausibility, single-view placement; called through reconstruction.triangulate.

Division follows NumPy (x / 0 is inf or NaN, never an error). Compiled once per machine,
cached beside this module.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from stereopose.geometry._kernels import dist3, dlt_point, in_view, view_errors
from stereopose.skeleton import (
    FACE,
    LEFT_EAR,
    LEFT_EYE,
    LEFT_HIP,
    LEFT_KNEE,
    LEFT_SHOULDER,
    NOSE,
    RIGHT_EAR,
    RIGHT_EYE,
    RIGHT_HIP,
    RIGHT_KNEE,
    RIGHT_SHOULDER,
)

_JIT = {"cache": True, "error_model": "numpy", "nogil": True}
# two-view solutions are tried between the most confident views of a joint, at most this many
# (all pairs of 12 views: 66; of 64, 2,016 pairs each scored over 64 views), and scored over all
MAX_SEEDS = 12


@njit(**_JIT)
def _seeds(w: np.ndarray, has: np.ndarray, k: int, seed: np.ndarray) -> None:
    """Into seed (C,): the views of `has`, or the k of them with the largest weights."""
    C = w.shape[0]
    n = 0
    for c in range(C):
        seed[c] = has[c]
        n += has[c]
    if n <= k:
        return
    order = np.argsort(-w)
    taken = 0
    for i in range(C):
        c = order[i]
        seed[c] = has[c] and taken < k
        taken += seed[c]


@njit(**_JIT)
def _best_pair(
    xy: np.ndarray,
    w: np.ndarray,
    has: np.ndarray,
    P: np.ndarray,
    focal: np.ndarray,
    thr: np.ndarray,
    inl: np.ndarray,
    best_inl: np.ndarray,
    Xk: np.ndarray,
    e: np.ndarray,
    seed: np.ndarray,
) -> bool:
    """Of every two-view solution of one joint (xy (C, 2), w (C,) among the views `has`, the
    pairs of its MAX_SEEDS most confident), the views agreeing (error < thr (C,)) with the one
    scored best by their confidence (ties to the tighter fit), into best_inl (C,); false when
    no pair gives a point. inl, Xk, e, seed: scratch arrays (C,), (3,), (C,), (C,)."""
    C = xy.shape[0]
    best = -np.inf
    found = False
    _seeds(w, has, MAX_SEEDS, seed)
    for a in range(C):
        if not seed[a]:
            continue
        for b in range(a + 1, C):
            if not seed[b]:
                continue
            for c in range(C):
                inl[c] = (c - a) * (c - b) == 0  # the pair itself
            dlt_point(xy, w, inl, P, Xk)
            if not np.isfinite(Xk[0]):
                continue
            view_errors(Xk, xy, P, focal, e)
            score = 0.0
            for c in range(C):
                inl[c] = has[c] and e[c] < thr[c]
                if inl[c]:
                    score += w[c] - 1e-3 * e[c] / thr[c]
            if not found or score > best:
                best = score
                found = True
                for c in range(C):
                    best_inl[c] = inl[c]
    return found


@njit(**_JIT)
def select_views(
    xy: np.ndarray,
    w: np.ndarray,
    P: np.ndarray,
    focal: np.ndarray,
    thr: np.ndarray,
    X_all: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per joint, the views that agree and the point they give.

    xy: (G, J, C, 2); w: (G, J, C) weights (0: unused); P: (C, 3, 4); focal: (C,);
    thr: (G, C) agreement threshold in pixels; X_all: (G, J, 3) weighted DLT over all views.
    Where every view of a joint agrees with X_all (or it has two views or fewer), X_all stands.
    Otherwise every two-view solution is scored by the confidence of the views agreeing with it
    (ties to the tighter fit), and the point is the weighted DLT over the best one's agreeing
    views, which are kept where within 1.5 thr of it. Where fewer than two views are kept, all
    views and X_all are used. Returns X (G, J, 3), used (G, J, C) and the errors of every view
    (G, J, C) in pixels. With more than MAX_SEEDS views, the pairs are those of its most
    confident MAX_SEEDS views (each still scored over every view).
    """
    G, J, C = w.shape
    X = X_all.copy()
    used = np.zeros((G, J, C), dtype=np.bool_)
    err = np.full((G, J, C), np.nan)
    e_all = np.empty(C)
    e = np.empty(C)
    Xk = np.empty(3)
    Xr = np.empty(3)
    has = np.empty(C, dtype=np.bool_)
    inl = np.empty(C, dtype=np.bool_)
    best_inl = np.empty(C, dtype=np.bool_)
    seed = np.empty(C, dtype=np.bool_)
    for g in range(G):
        for j in range(J):
            seen = 0
            for c in range(C):
                has[c] = w[g, j, c] > 0.0
                seen += has[c]
            view_errors(X_all[g, j], xy[g, j], P, focal, e_all)
            n_used = 0
            for c in range(C):
                u = has[c] and e_all[c] < thr[g, c]
                used[g, j, c] = u
                n_used += u
                err[g, j, c] = e_all[c]
            finite = np.isfinite(X_all[g, j, 0])
            if seen > 2 and (n_used < seen or not finite):
                found = _best_pair(
                    xy[g, j], w[g, j], has, P, focal, thr[g], inl, best_inl, Xk, e, seed
                )
                if found:
                    dlt_point(xy[g, j], w[g, j], best_inl, P, Xr)
                    view_errors(Xr, xy[g, j], P, focal, e)
                    n_used = 0
                    for c in range(C):
                        u = best_inl[c] and e[c] < 1.5 * thr[g, c]
                        used[g, j, c] = u
                        n_used += u
                        err[g, j, c] = e[c]
                    X[g, j, 0], X[g, j, 1], X[g, j, 2] = Xr[0], Xr[1], Xr[2]
                else:
                    n_used = 0
                    for c in range(C):
                        used[g, j, c] = False
                    X[g, j, 0] = X[g, j, 1] = X[g, j, 2] = np.nan
            if n_used < 2:
                X[g, j, 0], X[g, j, 1], X[g, j, 2] = X_all[g, j, 0], X_all[g, j, 1], X_all[g, j, 2]
                for c in range(C):
                    used[g, j, c] = has[c]
                    err[g, j, c] = e_all[c]
    return X, used, err


@njit(**_JIT)
def _lead(lx: float, ly: float, rx: float, ry: float) -> float:
    """How far the horizontal offset (lx, ly) reaches ahead, ahead being up x (rx, ry)."""
    return (ly * rx - lx * ry) / np.sqrt(rx * rx + ry * ry)


@njit(**_JIT)
def body_orientation(
    X: np.ndarray,
    face_margin_m: float,
    thigh_margin_m: float,
    head_radius_m: float,
    head_width_m: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Per person (G, 17, 3): whether the labels are mirrored as a whole (the face behind the
    shoulders and the nose behind the ears, with z up) and whether the legs are (each knee
    nearer the other side's hip); see triangulate.body_orientation."""
    G = X.shape[0]
    flip_upper = np.zeros(G, dtype=np.bool_)
    flip_legs = np.zeros(G, dtype=np.bool_)
    for g in range(G):
        # the head's sides: the ears, or the eyes without them
        ears = np.isfinite(X[g, LEFT_EAR, 0]) and np.isfinite(X[g, RIGHT_EAR, 0])
        hl, hr = (LEFT_EAR, RIGHT_EAR) if ears else (LEFT_EYE, RIGHT_EYE)
        mx = 0.5 * (X[g, hl, 0] + X[g, hr, 0])
        my = 0.5 * (X[g, hl, 1] + X[g, hr, 1])
        mz = 0.5 * (X[g, hl, 2] + X[g, hr, 2])
        off = np.sqrt(
            (X[g, NOSE, 0] - mx) ** 2 + (X[g, NOSE, 1] - my) ** 2 + (X[g, NOSE, 2] - mz) ** 2
        )
        stray = off >= head_radius_m or dist3(X, g, hl, hr) >= head_width_m  # NaN: False
        # the body's left-to-right axis: shoulders plus hips, whichever are known
        rx = ry = 0.0
        axes = 0
        for left, right in ((LEFT_SHOULDER, RIGHT_SHOULDER), (LEFT_HIP, RIGHT_HIP)):
            dx = X[g, right, 0] - X[g, left, 0]
            dy = X[g, right, 1] - X[g, left, 1]
            if np.isfinite(dx) and np.isfinite(dy):
                rx += dx
                ry += dy
                axes += 1
        if axes == 0:
            rx = ry = np.nan
        fx = fy = 0.0
        k = 0
        for j in FACE:
            if np.isfinite(X[g, j, 0]) and not (j == NOSE and stray):
                fx += X[g, j, 0]
                fy += X[g, j, 1]
                k += 1
        ahead = 0.0
        if k > 0:
            lx = fx / k - 0.5 * (X[g, LEFT_SHOULDER, 0] + X[g, RIGHT_SHOULDER, 0])
            ly = fy / k - 0.5 * (X[g, LEFT_SHOULDER, 1] + X[g, RIGHT_SHOULDER, 1])
            shoulders = _lead(lx, ly, rx, ry)
            if np.isfinite(shoulders):
                ahead += shoulders
        if not stray:
            lx, ly = X[g, NOSE, 0] - mx, X[g, NOSE, 1] - my
            head = _lead(lx, ly, rx, ry)
            if not np.isfinite(head):  # no body axis: the head's own
                head = _lead(lx, ly, X[g, hr, 0] - X[g, hl, 0], X[g, hr, 1] - X[g, hl, 1])
            if np.isfinite(head):
                ahead += head
        flip_upper[g] = ahead < -face_margin_m
        h0, h1 = (RIGHT_HIP, LEFT_HIP) if flip_upper[g] else (LEFT_HIP, RIGHT_HIP)
        d00 = dist3(X, g, h0, LEFT_KNEE)
        d01 = dist3(X, g, h0, RIGHT_KNEE)
        d10 = dist3(X, g, h1, LEFT_KNEE)
        d11 = dist3(X, g, h1, RIGHT_KNEE)
        flip_legs[g] = d01 + d10 < d00 + d11 - thigh_margin_m
    return flip_upper, flip_legs


@njit(**_JIT)
def chain_flips(X: np.ndarray, chains: np.ndarray, margin_m: float) -> np.ndarray:
    """(G, K) whether the child pair of each chain row (parent left, parent right, child left,
    child right) of `chains` (K, 4) hangs from the other side: the cross distances to the
    parents shorter than the direct ones by more than margin_m (NaN: no)."""
    G = X.shape[0]
    K = chains.shape[0]
    out = np.zeros((G, K), dtype=np.bool_)
    for g in range(G):
        for k in range(K):
            pl, pr, cl, cr = chains[k, 0], chains[k, 1], chains[k, 2], chains[k, 3]
            same = dist3(X, g, pl, cl) + dist3(X, g, pr, cr)
            cross = dist3(X, g, pl, cr) + dist3(X, g, pr, cl)
            out[g, k] = cross < same - margin_m
    return out


@njit(**_JIT)
def implausibility(
    X: np.ndarray,
    bones_left: np.ndarray,
    bones_right: np.ndarray,
    bones: np.ndarray,
    max_m: np.ndarray,
) -> np.ndarray:
    """(G,) how far each skeleton X (G, 17, 3) is from a possible body: the sum of
    |left - right| bone lengths over the sum of their means, over the bones (B, 2) whose both
    sides are known (0 where none is), plus, for each bone of `bones` (K, 2), its length's
    excess over max_m (K,) as a fraction of max_m."""
    G, B, K = X.shape[0], bones_left.shape[0], bones.shape[0]
    out = np.empty(G)
    for g in range(G):
        num = den = 0.0
        for b in range(B):
            lo = dist3(X, g, bones_left[b, 0], bones_left[b, 1])
            hi = dist3(X, g, bones_right[b, 0], bones_right[b, 1])
            if np.isfinite(lo) and np.isfinite(hi):
                num += abs(lo - hi)
                den += 0.5 * (lo + hi)
        score = num / den if den > 0.0 else 0.0
        for k in range(K):
            length = dist3(X, g, bones[k, 0], bones[k, 1])
            if length > max_m[k]:  # NaN compares False
                score += length / max_m[k] - 1.0
        out[g] = score
    return out


@njit(**_JIT)
def place_single_views(
    X: np.ndarray,
    used: np.ndarray,
    xy: np.ndarray,
    w: np.ndarray,
    centers: np.ndarray,
    R: np.ndarray,
    anchors: np.ndarray,
) -> np.ndarray:
    """Joints (NaN in X (G, J, 3)) that views report (w (G, J, C) > 0) placed on the ray of
    their strongest view, at the point nearest the first reconstructed joint of their row of
    anchors (J, A) (-1: none); two passes, so a joint can hang from one placed in the first.
    X and used (G, J, C) are updated in place; returns (G, J) the joints placed."""
    G, J, C = w.shape
    A = anchors.shape[1]
    placed = np.zeros((G, J), dtype=np.bool_)
    for _ in range(2):
        for j in range(J):
            for g in range(G):
                if np.isfinite(X[g, j, 0]) or placed[g, j]:
                    continue
                c = -1
                best = 0.0
                for k in range(C):
                    if w[g, j, k] > best:
                        best = w[g, j, k]
                        c = k
                if c < 0:
                    continue
                a = -1
                for i in range(A):
                    cand = anchors[j, i]
                    if cand >= 0 and np.isfinite(X[g, cand, 0]):
                        a = cand
                        break
                if a < 0:
                    continue
                x, y = xy[g, j, c, 0], xy[g, j, c, 1]
                # ray direction in the world: R^T (x, y, 1), normalised
                dx = R[c, 0, 0] * x + R[c, 1, 0] * y + R[c, 2, 0]
                dy = R[c, 0, 1] * x + R[c, 1, 1] * y + R[c, 2, 1]
                dz = R[c, 0, 2] * x + R[c, 1, 2] * y + R[c, 2, 2]
                norm = np.sqrt(dx * dx + dy * dy + dz * dz)
                dx, dy, dz = dx / norm, dy / norm, dz / norm
                depth = (
                    (X[g, a, 0] - centers[c, 0]) * dx
                    + (X[g, a, 1] - centers[c, 1]) * dy
                    + (X[g, a, 2] - centers[c, 2]) * dz
                )
                if not (depth > 0.0):
                    continue
                X[g, j, 0] = centers[c, 0] + depth * dx
                X[g, j, 1] = centers[c, 1] + depth * dy
                X[g, j, 2] = centers[c, 2] + depth * dz
                used[g, j, c] = True
                placed[g, j] = True
    return placed


@njit(**_JIT)
def plausible(
    X: np.ndarray,
    used: np.ndarray,
    members: np.ndarray,
    delivered: np.ndarray,
    P: np.ndarray,
    lo: np.ndarray,
    hi: np.ndarray,
    limb_a: np.ndarray,
    limb_b: np.ndarray,
    max_limb_m: float,
    min_joints: int,
    floor_tolerance_m: float,
    max_height_m: float,
    min_view_fraction: float,
    in_view_joints: int,
) -> np.ndarray:
    """(G,) which reconstructed people X (G, J, 3) are plausible; in place, the outer joint of
    each limb (limb_a -> limb_b, (L,)) longer than max_limb_m is dropped (NaN) and used
    (G, J, C) cleared for the joints not reconstructed. A person needs min_joints joints seen
    in two views or more, no joint below -floor_tolerance_m, at most max_height_m from the
    lowest joint to the highest, and detections (members (G, C) >= 0) in at least
    min_view_fraction of the cameras with a frame (delivered (C,)) that should see them (their
    detections' or >= in_view_joints joints inside the image bounds lo, hi (C, 2))."""
    G, J, C = used.shape
    L = limb_a.shape[0]
    keep = np.zeros(G, dtype=np.bool_)
    bad = np.zeros(L, dtype=np.bool_)
    for g in range(G):
        for k in range(L):  # every limb judged before any joint is dropped
            bad[k] = dist3(X, g, limb_a[k], limb_b[k]) > max_limb_m  # NaN: False
        for k in range(L):
            if bad[k]:
                X[g, limb_b[k], 0] = X[g, limb_b[k], 1] = X[g, limb_b[k], 2] = np.nan
    seen = in_view(X, P, lo, hi, in_view_joints)
    for g in range(G):
        strong = 0
        zmin, zmax = np.inf, -np.inf
        for j in range(J):
            valid = np.isfinite(X[g, j, 0]) and np.isfinite(X[g, j, 1]) and np.isfinite(X[g, j, 2])
            n = 0
            for c in range(C):
                used[g, j, c] = used[g, j, c] and valid
                n += used[g, j, c]
            if valid:
                strong += n >= 2
                zmin = min(zmin, X[g, j, 2])
                zmax = max(zmax, X[g, j, 2])
        views = expected = 0
        for c in range(C):
            views += members[g, c] >= 0
            expected += (seen[g, c] or members[g, c] >= 0) and delivered[c]
        keep[g] = (
            strong >= min_joints
            and zmin >= -floor_tolerance_m
            and zmax - zmin <= max_height_m
            and views >= min_view_fraction * expected
        )
    return keep
