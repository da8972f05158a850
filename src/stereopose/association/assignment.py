"""Minimum-cost one-to-one assignment (the Hungarian problem), for the small matrices of one
frame: detections to detections, detections to expected poses, people to tracks.

The same algorithm as SciPy's `linear_sum_assignment` (Crouse's shortest augmenting paths),
compiled with the other association loops: the same assignments, ties included, without
importing scipy.optimize into every run.
"""

from __future__ import annotations

import numpy as np

from stereopose.arrays import checked
from stereopose.association._kernels import assignment


def linear_sum_assignment(cost: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rows and columns (K,) each of a minimum-cost assignment of cost (R, C), K = min(R, C),
    rows in increasing order, as scipy.optimize.linear_sum_assignment. Costs are finite (the
    callers give forbidden pairs a large finite cost); NaN is refused."""
    c = checked(cost, "cost", (None, None))
    if np.isnan(c).any():
        raise ValueError("cost contains NaN")
    R, C = c.shape
    if R == 0 or C == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    col4row = assignment(c if R <= C else np.ascontiguousarray(c.T))  # for R > C: columns
    if col4row.size == 0:
        raise ValueError("cost matrix is infeasible")
    if R <= C:
        return np.arange(R), col4row
    order = np.argsort(col4row, kind="stable")
    return col4row[order], order
