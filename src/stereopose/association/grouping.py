"""Consistent groups of detections across all cameras: one detection per camera per person."""

from __future__ import annotations

import functools

import numpy as np

from stereopose.association.assignment import linear_sum_assignment

_BIG = 1e9


@functools.lru_cache(maxsize=64)
def upper_pairs(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Index pairs (i < j) of n items, as two arrays."""
    return np.triu_indices(n, k=1)


def pairwise_matches(cost: np.ndarray, camera: np.ndarray, max_cost: float) -> np.ndarray:
    """Globally optimal one-to-one matches for every camera pair (Hungarian).

    cost: (N, N) detection costs; camera: (N,) camera index of each detection, detections
    ordered by camera. Returns (M, 3) float rows (detection n < detection m, cost), only
    matches with cost <= max_cost.

    For every camera pair the detections of the camera with fewer of them pick their cheapest
    partner in the other camera; where no two pick the same partner, that is the optimal
    assignment (the sum of row minima bounds every assignment from below), found for all pairs
    at once. Only pairs with a conflict go through the Hungarian algorithm.

    Costs above max_cost are gated out before the assignment: otherwise the assignment could
    give a detection a partner beyond max_cost (then dropped) to spare a cheaper match
    elsewhere, leaving the detection's true partner unmatched too.
    """
    N = cost.shape[0]
    cost = np.where(cost <= max_cost, cost, np.inf)
    per_camera = np.bincount(camera)
    cams = np.flatnonzero(per_camera)
    if cams.size < 2:
        return np.zeros((0, 3))
    counts = per_camera[cams]
    start = np.cumsum(counts) - counts
    # (N, Q) cheapest partner of every detection in every camera that has detections
    slot = np.arange(counts.max())
    pad = np.where(slot[None] < counts[:, None], start[:, None] + slot[None], -1)
    sub = np.where(pad[None] >= 0, cost[:, np.maximum(pad, 0)], np.inf)  # (N, Q, Pmax)
    best = pad[np.arange(cams.size)[None], sub.argmin(-1)]  # (N, Q)
    q_of = np.searchsorted(cams, camera)  # (N,) camera slot of each detection
    qa, qb = upper_pairs(cams.size)
    small = np.where(counts[qa] <= counts[qb], qa, qb)  # side that picks
    other = np.where(counts[qa] <= counts[qb], qb, qa)
    # who picks: detection n of camera `small[k]` picks best[n, other[k]]
    pick_pair = np.full((cams.size, cams.size), -1)
    pick_pair[small, other] = np.arange(qa.size)
    k_of = pick_pair[q_of[:, None], np.arange(cams.size)[None]]  # (N, Q) pair index or -1
    n_idx, q_idx = np.nonzero((k_of >= 0) & np.isfinite(sub.min(-1)))
    m_idx = best[n_idx, q_idx]
    k_idx = k_of[n_idx, q_idx]
    picks = np.zeros((qa.size, N), dtype=np.int64)
    np.add.at(picks, (k_idx, m_idx), 1)
    conflict = picks.max(axis=1) > 1  # (K,)
    ok = ~conflict[k_idx]
    rows_n, rows_m = [n_idx[ok]], [m_idx[ok]]
    finite = np.where(np.isfinite(cost), cost, _BIG)
    for k in np.flatnonzero(conflict):
        a = np.arange(int(start[qa[k]]), int(start[qa[k]] + counts[qa[k]]))
        b = np.arange(int(start[qb[k]]), int(start[qb[k]] + counts[qb[k]]))
        r, c = linear_sum_assignment(finite[np.ix_(a, b)])
        rows_n.append(a[r])
        rows_m.append(b[c])
    first, second = np.concatenate(rows_n), np.concatenate(rows_m)
    n, m = np.minimum(first, second), np.maximum(first, second)
    c = cost[n, m]
    keep = c <= max_cost
    return np.stack([n[keep], m[keep], c[keep]], axis=1).astype(np.float64)


def group_detections(cost: np.ndarray, camera: np.ndarray, max_cost: float) -> list[np.ndarray]:
    """Group detections of one frame into people.

    cost: (N, N) symmetric costs (inf: impossible); camera: (N,) camera of each detection,
    detections ordered by camera.
    Pairwise Hungarian matches are merged cheapest first; two groups merge only when they share
    no camera and the mean cost over all their cross pairs (average linkage) stays within
    max_cost, which keeps groups consistent over more than two cameras.
    Returns groups of >= 2 detection indices, each array sorted by camera.
    """
    N = cost.shape[0]
    if N == 0:
        return []
    edges = pairwise_matches(cost, camera, max_cost)
    if len(edges) == 0:
        return []
    edges = edges[np.argsort(edges[:, 2], kind="stable")]
    finite = np.isfinite(cost)
    # Sum [0] and count [1] of finite costs between groups, kept up to date as groups merge.
    link = np.stack([np.where(finite, cost, 0.0), finite.astype(np.float64)])
    label = list(range(N))
    cams_of = [1 << int(c) for c in camera]
    members: dict[int, list[int]] = {n: [n] for n in range(N)}
    for n, m in edges[:, :2].astype(int).tolist():
        a, b = label[n], label[m]
        if a == b or cams_of[a] & cams_of[b]:
            continue
        total, count = link[:, a, b]
        if total > max_cost * count:
            continue
        if len(members[a]) < len(members[b]):
            a, b = b, a
        for k in members[b]:
            label[k] = a
        members[a].extend(members.pop(b))
        cams_of[a] |= cams_of[b]
        link[:, a] += link[:, b]
        link[:, :, a] += link[:, :, b]
    # detections are numbered camera by camera, so sorting by index sorts by camera
    groups = [np.array(sorted(g)) for g in members.values() if len(g) > 1]
    groups.sort(key=lambda g: int(g[0]))
    return groups
