"""Consistent groups of detections across all cameras: one detection per camera per person."""

from __future__ import annotations

import numpy as np
from scipy.optimize import linear_sum_assignment

_BIG = 1e9


def pairwise_matches(cost: np.ndarray, camera: np.ndarray, max_cost: float) -> np.ndarray:
    """Globally optimal one-to-one matches for every camera pair (Hungarian).

    cost: (N, N) detection costs; camera: (N,) camera index of each detection.
    Returns (M, 3) float rows (detection n, detection m, cost), only matches with
    cost <= max_cost.
    """
    rows = []
    cams = np.unique(camera)
    members = [np.flatnonzero(camera == c) for c in cams]
    for i in range(len(cams)):
        for j in range(i + 1, len(cams)):
            a, b = members[i], members[j]
            sub = cost[np.ix_(a, b)]
            if not np.isfinite(sub).any():
                continue
            r, c = linear_sum_assignment(np.where(np.isfinite(sub), sub, _BIG))
            keep = sub[r, c] <= max_cost
            rows.extend(zip(a[r[keep]], b[c[keep]], sub[r[keep], c[keep]], strict=True))
    return np.array(rows, dtype=np.float64).reshape(-1, 3)


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
    label = np.arange(N)
    cams_of = [1 << int(c) for c in camera]
    members: dict[int, list[int]] = {n: [n] for n in range(N)}
    finite = np.isfinite(cost)
    for n_f, m_f, _ in edges:
        a, b = label[int(n_f)], label[int(m_f)]
        if a == b or cams_of[a] & cams_of[b]:
            continue
        ga, gb = members[a], members[b]
        sub = cost[np.ix_(ga, gb)]
        ok = finite[np.ix_(ga, gb)]
        if sub[ok].mean() > max_cost:
            continue
        if len(ga) < len(gb):
            a, b, ga, gb = b, a, gb, ga
        ga.extend(gb)
        label[gb] = a
        cams_of[a] |= cams_of[b]
        del members[b]
    groups = [np.array(sorted(g, key=lambda n: camera[n])) for g in members.values() if len(g) > 1]
    groups.sort(key=lambda g: int(g[0]))
    return groups
