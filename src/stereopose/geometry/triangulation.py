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
    # Least squares with X homogeneous coordinate fixed to 1: (A3^T A3) X = -A3^T a4, solved
    # in closed form (adjugate of the symmetric 3 x 3 matrix) for every point at once.
    A = np.concatenate([rows_x, rows_y], axis=-2)  # (..., 2V, 4)
    N = np.matmul(A.swapaxes(-1, -2), A)  # (..., 4, 4)
    M, rhs = N[..., :3, :3], -N[..., :3, 3]
    X = _solve_sym3(M, rhs)
    enough = (w > 0).sum(axis=-1) >= 2
    return np.where(enough[..., None] & np.isfinite(X).all(axis=-1, keepdims=True), X, np.nan)


def _solve_sym3(M: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Solve (..., 3, 3) symmetric systems M x = b (..., 3); NaN where (near) singular."""
    a, d, f = M[..., 0, 0], M[..., 1, 1], M[..., 2, 2]
    bb, c, e = M[..., 0, 1], M[..., 0, 2], M[..., 1, 2]
    A = d * f - e * e
    B = c * e - bb * f
    C = bb * e - c * d
    D = a * f - c * c
    E = bb * c - a * e
    F = a * d - bb * bb
    det = a * A + bb * B + c * C
    scale = (a + d + f) ** 3
    with np.errstate(invalid="ignore", divide="ignore"):
        ok = np.abs(det) > 1e-12 * np.abs(scale)
        inv_det = np.where(ok, 1.0 / det, np.nan)
    x0, x1, x2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack(
        [
            (A * x0 + B * x1 + C * x2) * inv_det,
            (B * x0 + D * x1 + E * x2) * inv_det,
            (C * x0 + E * x1 + F * x2) * inv_det,
        ],
        axis=-1,
    )
