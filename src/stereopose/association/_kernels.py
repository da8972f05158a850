"""Compiled loops of the association (numba): epipolar distances and costs of detection
pairs, detection sizes, claims of detections by expected poses; called through the checked
wrappers of association.affinity and association.claims.

Division follows NumPy (x / 0 is inf or NaN, never an error). Compiled once per machine,
cached beside this module.
"""

from __future__ import annotations

import numpy as np
from numba import njit

_JIT = {"cache": True, "error_model": "numpy", "nogil": True}


@njit(**_JIT)
def epipolar_pair_distances(
    xy: np.ndarray,
    size: np.ndarray,
    camera: np.ndarray,
    E: np.ndarray,
    first: np.ndarray,
    second: np.ndarray,
    swap: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Per-joint normalised symmetric epipolar distances of detection pairs.

    xy: (N, 17, 2) ideal coordinates, finite (missing joints as 0: they never vote);
    size: (N,); camera: (N,); E: (C, C, 3, 3); first, second: (M,) detection pairs. Returns
    same (M, 17), the distance of joint j of `first` to joint j of `second`, each side's
    point-to-line distance divided by its detection's size, and cross (M, 17), the same
    against the mirror joint swap[j] of `second` (see association.affinity.epipolar_distances).
    """
    M, J = first.shape[0], xy.shape[1]
    same = np.empty((M, J))
    cross = np.empty((M, J))
    lm = np.empty((J, 3))  # lines of first's joints in second's image
    wm = np.empty(J)
    wn = np.empty(J)
    for k in range(M):
        n, m = first[k], second[k]
        ca, cb = camera[n], camera[m]
        for j in range(J):
            xn, yn = xy[n, j, 0], xy[n, j, 1]
            xm, ym = xy[m, j, 0], xy[m, j, 1]
            for r in range(3):
                lm[j, r] = E[ca, cb, r, 0] * xn + E[ca, cb, r, 1] * yn + E[ca, cb, r, 2]
            a = E[cb, ca, 0, 0] * xm + E[cb, ca, 0, 1] * ym + E[cb, ca, 0, 2]
            b = E[cb, ca, 1, 0] * xm + E[cb, ca, 1, 1] * ym + E[cb, ca, 1, 2]
            wm[j] = 0.5 / np.sqrt(lm[j, 0] * lm[j, 0] + lm[j, 1] * lm[j, 1]) / size[m]
            wn[j] = 0.5 / np.sqrt(a * a + b * b) / size[n]
        for j in range(J):
            s = swap[j]
            xm, ym = xy[m, j, 0], xy[m, j, 1]
            xs, ys = xy[m, s, 0], xy[m, s, 1]
            same[k, j] = abs(lm[j, 0] * xm + lm[j, 1] * ym + lm[j, 2]) * (wm[j] + wn[j])
            cross[k, j] = abs(lm[j, 0] * xs + lm[j, 1] * ys + lm[j, 2]) * (wm[j] + wn[s])
    return same, cross


@njit(**_JIT)
def pair_costs(
    N: int,
    first: np.ndarray,
    second: np.ndarray,
    same: np.ndarray,
    cross: np.ndarray,
    ok: np.ndarray,
    swap: np.ndarray,
    min_common: int,
) -> np.ndarray:
    """(N, N) symmetric cost of detection pairs: the mean over joints confident (ok (N, 17)) in
    both of the distances same (M, 17), or of cross with the second's labels exchanged, the
    lower of the two; inf with fewer than min_common shared joints, and for pairs not listed
    (see association.affinity.epipolar_costs)."""
    cost = np.full((N, N), np.inf)
    J = ok.shape[1]
    for k in range(first.shape[0]):
        n, m = first[k], second[k]
        best = np.inf
        for lab in range(2):
            total = 0.0
            count = 0
            for j in range(J):
                jm = swap[j] if lab == 1 else j
                if ok[n, j] and ok[m, jm]:
                    total += same[k, j] if lab == 0 else cross[k, j]
                    count += 1
            if count >= min_common and count > 0:
                c = total / count
                if np.isfinite(c) and c < best:
                    best = c
        cost[n, m] = cost[m, n] = best
    return cost


@njit(**_JIT)
def box_diagonals(xy: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """(N,) diagonal of the box around the masked joints of each detection (N, 17, 2); NaN
    with fewer than two."""
    N, J = mask.shape
    out = np.full(N, np.nan)
    for n in range(N):
        x0 = y0 = np.inf
        x1 = y1 = -np.inf
        k = 0
        for j in range(J):
            if mask[n, j]:
                x, y = xy[n, j, 0], xy[n, j, 1]
                x0, x1 = min(x0, x), max(x1, x)
                y0, y1 = min(y0, y), max(y1, y)
                k += 1
        if k >= 2:
            out[n] = np.sqrt((x1 - x0) ** 2 + (y1 - y0) ** 2)
    return out


@njit(**_JIT)
def claim_costs(
    xy: np.ndarray,
    ok: np.ndarray,
    size: np.ndarray,
    camera: np.ndarray,
    proj: np.ndarray,
    swap: np.ndarray,
    parts: np.ndarray,
    min_common: int,
) -> tuple[np.ndarray, np.ndarray]:
    """Cost of every detection against every predicted pose, labels as detected or exchanged.

    xy: (N, 17, 2) detections' ideal coordinates; ok: (N, 17) confident joints; size: (N,);
    camera: (N,) camera of each detection; proj: (T, 17, C, 2) predicted poses reprojected
    (NaN where unknown); swap: (17,) mirror joint; parts: (17, 2) joint-to-part weights;
    min_common: joints needed. Returns best (N, T), the mean distance over shared joints
    divided by the detection's size, the lower of the two labelings (inf with fewer than
    min_common joints), and per labeling (2, N, T, 2) the mean distance per body part (NaN
    where the part shares no joint).
    """
    N, J = ok.shape
    T = proj.shape[0]
    P = parts.shape[1]
    best = np.full((N, T), np.inf)
    part = np.full((2, N, T, P), np.nan)
    psum = np.empty(P)
    pcnt = np.empty(P)
    for n in range(N):
        c = camera[n]
        for t in range(T):
            for lab in range(2):
                total = 0.0
                count = 0
                for p in range(P):
                    psum[p] = 0.0
                    pcnt[p] = 0.0
                for j in range(J):
                    k = swap[j] if lab == 1 else j
                    if not ok[n, k]:
                        continue
                    dx = xy[n, k, 0] - proj[t, j, c, 0]
                    dy = xy[n, k, 1] - proj[t, j, c, 1]
                    d = np.sqrt(dx * dx + dy * dy)
                    if d != d:
                        continue
                    total += d
                    count += 1
                    for p in range(P):
                        if parts[j, p] != 0.0:
                            psum[p] += d * parts[j, p]
                            pcnt[p] += parts[j, p]
                for p in range(P):
                    if pcnt[p] > 0.0:
                        part[lab, n, t, p] = psum[p] / pcnt[p]
                if count >= min_common and count > 0:
                    cost = total / (count * size[n])
                    if cost == cost and cost < best[n, t]:
                        best[n, t] = cost
    return best, part


@njit(**_JIT)
def _augmenting_path(
    cost: np.ndarray,
    u: np.ndarray,
    v: np.ndarray,
    path: np.ndarray,
    row4col: np.ndarray,
    spc: np.ndarray,
    i: int,
    SR: np.ndarray,
    SC: np.ndarray,
    remaining: np.ndarray,
) -> tuple[int, float]:
    """One shortest augmenting path from row i (Crouse's algorithm, as SciPy's
    linear_sum_assignment); returns (sink column or -1 when infeasible, its path cost)."""
    nc = cost.shape[1]
    min_val = 0.0
    num_remaining = nc
    for it in range(nc):
        # filled in reverse order, so that a constant cost matrix gives the identity
        remaining[it] = nc - it - 1
    SR[:] = False
    SC[:] = False
    spc[:] = np.inf
    sink = -1
    while sink == -1:
        index = -1
        lowest = np.inf
        SR[i] = True
        for it in range(num_remaining):
            j = remaining[it]
            r = min_val + cost[i, j] - u[i] - v[j]
            if r < spc[j]:
                path[j] = i
                spc[j] = r
            if spc[j] < lowest or (spc[j] == lowest and row4col[j] == -1):
                lowest = float(spc[j])
                index = it
        min_val = lowest
        if min_val == np.inf:
            return -1, min_val
        j = remaining[index]
        if row4col[j] == -1:
            sink = j
        else:
            i = int(row4col[j])
        SC[j] = True
        num_remaining -= 1
        remaining[index] = remaining[num_remaining]
    return sink, min_val


@njit(**_JIT)
def assignment(cost: np.ndarray) -> np.ndarray:
    """Minimum-cost assignment of the rows of cost (nr, nc) to its columns, nr <= nc, each
    row to a distinct column; costs finite or inf (forbidden). Returns col4row (nr,), or an
    empty array when no complete assignment avoids the forbidden pairs."""
    nr, nc = cost.shape
    u = np.zeros(nr)
    v = np.zeros(nc)
    spc = np.empty(nc)
    path = np.full(nc, -1, dtype=np.int64)
    col4row = np.full(nr, -1, dtype=np.int64)
    row4col = np.full(nc, -1, dtype=np.int64)
    SR = np.zeros(nr, dtype=np.bool_)
    SC = np.zeros(nc, dtype=np.bool_)
    remaining = np.empty(nc, dtype=np.int64)
    for cur in range(nr):
        sink, min_val = _augmenting_path(cost, u, v, path, row4col, spc, cur, SR, SC, remaining)
        if sink < 0:
            return np.zeros(0, dtype=np.int64)
        u[cur] += min_val
        for i in range(nr):
            if SR[i] and i != cur:
                u[i] += min_val - spc[col4row[i]]
        for j in range(nc):
            if SC[j]:
                v[j] -= min_val - spc[j]
        j = sink
        while True:
            i = path[j]
            row4col[j] = i
            j, col4row[i] = col4row[i], j
            if i == cur:
                break
    return col4row
