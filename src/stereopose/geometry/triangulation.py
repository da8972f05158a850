"""Linear (DLT) triangulation, batched over any leading axes.

Points are ideal normalised image coordinates and cameras are [R | t] (3, 4), which keeps the
linear systems well conditioned without extra normalisation.
"""

from __future__ import annotations

import numpy as np


def triangulate_dlt(xy: np.ndarray, P: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Weighted DLT triangulation.

    xy: (..., V, 2) normalised coordinates of one point seen in V views (NaN where unseen).
    P: (..., V, 3, 4) or (V, 3, 4) cameras [R | t], world -> camera.
    weights: (..., V) non-negative; a view with weight 0 or NaN coordinates is ignored.
    Returns (..., 3) world points; NaN where fewer than 2 views have positive weight.
    """
    xy = np.asarray(xy, dtype=np.float64)
    if xy.ndim < 2 or xy.shape[-1] != 2:
        raise ValueError(f"xy must have shape (..., V, 2), got {xy.shape}")
    V = xy.shape[-2]
    if P.shape[-3:] != (V, 3, 4):
        raise ValueError(f"P must have shape (..., {V}, 3, 4), got {P.shape}")
    w = np.where(np.isfinite(xy).all(axis=-1), np.asarray(weights, dtype=np.float64), 0.0)
    w = np.where(w > 0, w, 0.0)
    x = np.nan_to_num(xy)
    # Two rows per view: x P3 - P1 and y P3 - P2, scaled by the view's weight.
    rows_x = x[..., 0:1] * P[..., 2, :] - P[..., 0, :]
    rows_y = x[..., 1:2] * P[..., 2, :] - P[..., 1, :]
    rows_x = rows_x * w[..., None]
    rows_y = rows_y * w[..., None]
    # Normal equations A^T A (4 x 4): the smallest eigenvector is the DLT solution.
    M = np.einsum("...vi,...vj->...ij", rows_x, rows_x) + np.einsum(
        "...vi,...vj->...ij", rows_y, rows_y
    )
    _, vecs = np.linalg.eigh(M)
    Xh = vecs[..., :, 0]
    with np.errstate(invalid="ignore", divide="ignore"):
        X = Xh[..., :3] / Xh[..., 3:4]
    enough = (w > 0).sum(axis=-1) >= 2
    return np.where(enough[..., None] & np.isfinite(X).all(axis=-1, keepdims=True), X, np.nan)
