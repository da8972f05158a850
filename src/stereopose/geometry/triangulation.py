"""Linear (DLT) triangulation, batched over any leading axes.

Points are ideal normalised image coordinates and cameras are [R | t] (3, 4), which keeps the
linear systems well conditioned without extra normalisation.
"""

from __future__ import annotations

import numpy as np

_NEXT = np.array([1, 2, 0])
_PREV = np.array([2, 0, 1])


def dlt_blocks(P: np.ndarray) -> np.ndarray:
    """(..., V, 3, 4) cameras -> (..., V * 4, 16) per-view blocks of A^T A.

    Each view adds the rows w (x P3 - P1) and w (y P3 - P2) to the DLT matrix A, so A^T A is a
    sum over views of w^2 [(x^2 + y^2) P3P3 - x (P1P3 + P3P1) - y (P2P3 + P3P2) + P1P1 + P2P2]:
    per-view coefficients times these four per-camera 4 x 4 blocks. They depend on the cameras
    only, so they can be computed once per rig.
    """
    P1, P2, P3 = P[..., 0, :], P[..., 1, :], P[..., 2, :]

    def outer(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        return a[..., :, None] * b[..., None, :]

    p13, p23 = outer(P1, P3), outer(P2, P3)
    blocks = np.stack(
        [
            outer(P3, P3),
            -(p13 + p13.swapaxes(-1, -2)),
            -(p23 + p23.swapaxes(-1, -2)),
            outer(P1, P1) + outer(P2, P2),
        ],
        axis=-3,
    )  # (..., V, 4, 4, 4)
    return blocks.reshape(*blocks.shape[:-4], blocks.shape[-4] * 4, 16)


def triangulate_dlt(
    xy: np.ndarray, P: np.ndarray | None, weights: np.ndarray, blocks: np.ndarray | None = None
) -> np.ndarray:
    """Weighted DLT triangulation.

    xy: (..., V, 2) normalised coordinates of one point seen in V views (NaN where unseen).
    P: (..., V, 3, 4) or (V, 3, 4) cameras [R | t], world -> camera.
    weights: (..., V) non-negative; a view with weight 0 or NaN coordinates is ignored.
    blocks: dlt_blocks(P), when already computed (P may then be None).
    Returns (..., 3) world points; NaN where fewer than 2 views have positive weight.
    """
    xy = np.asarray(xy, dtype=np.float64)
    if xy.ndim < 2 or xy.shape[-1] != 2:
        raise ValueError(f"xy must have shape (..., V, 2), got {xy.shape}")
    V = xy.shape[-2]
    if blocks is None:
        if P is None or P.shape[-3:] != (V, 3, 4):
            raise ValueError(f"P must have shape (..., {V}, 3, 4), got {np.shape(P)}")
        blocks = dlt_blocks(P)
    elif blocks.shape[-2:] != (V * 4, 16):
        raise ValueError(f"blocks must have shape (..., {V * 4}, 16), got {blocks.shape}")
    b = blocks
    seen = np.isfinite(xy)
    w = np.where(seen[..., 0] & seen[..., 1], np.asarray(weights, dtype=np.float64), 0.0)
    w2 = np.where(w > 0, w * w, 0.0)
    x = np.where(seen, xy, 0.0)
    coef = w2[..., None] * np.stack(
        [x[..., 0] ** 2 + x[..., 1] ** 2, x[..., 0], x[..., 1], np.ones_like(w2)], axis=-1
    )  # (..., V, 4)
    c = coef.reshape(*coef.shape[:-2], V * 4)
    if b.ndim == 2:
        N = c @ b
    elif b.ndim == 3 and c.shape[-2] == b.shape[0]:
        # one block set per item of the last batch axis: a batched matmul over that axis
        flat = c.reshape(-1, *c.shape[-2:]).swapaxes(0, 1)  # (K, n, V * 4)
        N = np.matmul(flat, b).swapaxes(0, 1)
    else:
        N = np.einsum("...i,...ij->...j", c, b)
    N = N.reshape(*c.shape[:-1], 4, 4)
    # Least squares with the homogeneous coordinate fixed to 1: (A3^T A3) X = -A3^T a4.
    X = _solve_sym3(N[..., :3, :3], -N[..., :3, 3])
    enough = (w > 0).sum(axis=-1) >= 2
    return np.where(enough[..., None] & np.isfinite(X[..., :1]), X, np.nan)


def _solve_sym3(M: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Solve (..., 3, 3) symmetric systems M x = b (..., 3) by the adjugate; NaN where
    (near) singular. Row i of the cofactor matrix is row(i+1) x row(i+2) of M, and for a
    symmetric M it is also row i of the adjugate."""
    r1, r2 = M[..., _NEXT, :], M[..., _PREV, :]
    cof = r1[..., _NEXT] * r2[..., _PREV] - r1[..., _PREV] * r2[..., _NEXT]
    det = np.einsum("...i,...i->...", M[..., 0, :], cof[..., 0, :])
    trace = M[..., 0, 0] + M[..., 1, 1] + M[..., 2, 2]
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        inv_det = np.where(np.abs(det) > 1e-12 * np.abs(trace) ** 3, 1.0 / det, np.nan)
    return np.einsum("...ij,...j->...i", cof, b) * inv_det[..., None]
