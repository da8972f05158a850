"""Consistent groups of detections across all cameras: one detection per camera per person."""

from __future__ import annotations

import numpy as np
from scipy.optimize import linear_sum_assignment

_BIG = 1e9


def _assignment(cost: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Minimum-cost one-to-one assignment of a (R, K) matrix (rows, columns).

    When every row's cheapest column is a different column (the usual case: people far apart),
    that is already optimal, as the sum of row minima bounds every assignment from below; only
    conflicts need the Hungarian algorithm.
    """
    R, K = cost.shape
    if R <= K:
        best = cost.argmin(axis=1)
        if np.bincount(best, minlength=K).max(initial=0) <= 1:
            return np.arange(R), best
    else:
        best = cost.argmin(axis=0)
        if np.bincount(best, minlength=R).max(initial=0) <= 1:
            order = np.argsort(best)
            return best[order], order
    return linear_sum_assignment(cost)


def pairwise_matches(cost: np.ndarray, camera: np.ndarray, max_cost: float) -> np.ndarray:
    """Globally optimal one-to-one matches for every camera pair (Hungarian).

    cost: (N, N) detection costs; camera: (N,) camera index of each detection.
    Returns (M, 3) float rows (detection n, detection m, cost), only matches with
    cost <= max_cost.
    """
    members = [np.flatnonzero(camera == c) for c in np.unique(camera)]
    finite = np.where(np.isfinite(cost), cost, _BIG)
    n_out, m_out = [], []
    for i, a in enumerate(members):
        rows = finite[a]
        for b in members[i + 1 :]:
            sub = rows[:, b]
            r, c = _assignment(sub)
            keep = sub[r, c] <= max_cost
            n_out.append(a[r[keep]])
            m_out.append(b[c[keep]])
    if not n_out:
        return np.zeros((0, 3))
    n = np.concatenate(n_out)
    m = np.concatenate(m_out)
    return np.stack([n, m, cost[n, m]], axis=1).astype(np.float64)


def group_detections(cost: np.ndarray, camera: np.ndarray, max_cost: float) -> list[np.ndarray]:
    """Group detections of one frame into people.

    cost: (N, N) symmetric costs (inf: impossible); camera: (N,) camera of each detection.
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
    # Sum and count of finite costs between groups, kept up to date as groups merge.
    total = np.where(finite, cost, 0.0)
    count = finite.astype(np.float64)
    label = list(range(N))
    cams_of = [1 << int(c) for c in camera]
    members: dict[int, list[int]] = {n: [n] for n in range(N)}
    for n, m in edges[:, :2].astype(int).tolist():
        a, b = label[n], label[m]
        if a == b or cams_of[a] & cams_of[b]:
            continue
        if total[a, b] > max_cost * count[a, b]:
            continue
        if len(members[a]) < len(members[b]):
            a, b = b, a
        for k in members[b]:
            label[k] = a
        members[a].extend(members.pop(b))
        cams_of[a] |= cams_of[b]
        total[a] += total[b]
        total[:, a] += total[:, b]
        count[a] += count[b]
        count[:, a] += count[:, b]
    groups = [np.array(sorted(g, key=lambda k: camera[k])) for g in members.values() if len(g) > 1]
    groups.sort(key=lambda g: int(g[0]))
    return groups
