"""Linear (DLT) triangulation, batched over any leading axes.

Points are ideal normalised image coordinates and cameras are [R | t] (3, 4), which keeps the
linear systems well conditioned without extra normalisation.
"""

from __future__ import annotations

import numpy as np

# N[:3, :3] entries a b c d f g (upper triangle) and N[:3, 3], in a flattened 4 x 4
_ENTRIES = np.array([0, 1, 2, 5, 6, 10, 3, 7, 11])


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
    seen = np.isfinite(xy[..., 0]) & np.isfinite(xy[..., 1])
    w = np.asarray(weights, dtype=np.float64)
    w2 = np.where(seen & (w > 0), w, 0.0) ** 2  # NaN or non-positive weight: view unused
    x = np.where(seen, xy[..., 0], 0.0)
    y = np.where(seen, xy[..., 1], 0.0)
    coef = np.empty((*w2.shape, 4))  # (..., V, 4) per-view coefficients of the blocks
    coef[..., 1] = w2 * x
    coef[..., 2] = w2 * y
    coef[..., 3] = w2
    coef[..., 0] = coef[..., 1] * x + coef[..., 2] * y
    c = coef.reshape(*coef.shape[:-2], V * 4)
    if b.ndim == 2:
        N = c @ b
    elif b.ndim == 3 and c.shape[-2] == b.shape[0]:
        # one block set per item of the last batch axis: a batched matmul over that axis
        flat = c.reshape(-1, *c.shape[-2:]).swapaxes(0, 1)  # (K, n, V * 4)
        N = np.matmul(flat, b).swapaxes(0, 1)
    else:
        N = np.einsum("...i,...ij->...j", c, b)
    # Least squares with the homogeneous coordinate fixed to 1: (A3^T A3) X = -A3^T a4; fewer
    # than two views leave it singular, which gives NaN.
    return _solve_normal_equations(N.reshape(*c.shape[:-1], 4, 4))


def _solve_normal_equations(N: np.ndarray) -> np.ndarray:
    """X (..., 3) minimising |A [X, 1]|^2 from N = A^T A (..., 4, 4): the symmetric 3 x 3
    system N[:3, :3] X = -N[:3, 3], solved by the adjugate; NaN where (near) singular."""
    e = N.reshape(*N.shape[:-2], 16)[..., _ENTRIES]
    a, b, c, d, f, g, r0, r1, r2 = np.moveaxis(e, -1, 0)  # M = [[a, b, c], [b, d, f], [c, f, g]]
    A, B, C = d * g - f * f, c * f - b * g, b * f - c * d  # adjugate, first row
    D, E, F = a * g - c * c, b * c - a * f, a * d - b * b
    det = a * A + b * B + c * C
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        inv = np.where(np.abs(det) > 1e-12 * np.abs(a + d + g) ** 3, -1.0 / det, np.nan)
    out = np.empty((*det.shape, 3))
    out[..., 0] = (A * r0 + B * r1 + C * r2) * inv
    out[..., 1] = (B * r0 + D * r1 + E * r2) * inv
    out[..., 2] = (C * r0 + E * r1 + F * r2) * inv
    return out
