"""Linear (DLT) triangulation, batched over any leading axes.

Points are ideal normalised image coordinates and cameras are [R | t] (3, 4), which keeps the
linear systems well conditioned without extra normalisation. The solve itself is the compiled
geometry._kernels.dlt_point, the one DLT every mode uses.
"""

from __future__ import annotations

import numpy as np

from stereopose.arrays import checked
from stereopose.geometry._kernels import dlt_all


def triangulate_dlt(xy: np.ndarray, P: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Weighted DLT triangulation.

    xy: (..., V, 2) normalised coordinates of one point seen in V views (NaN where unseen).
    P: (V, 3, 4) cameras [R | t], world -> camera.
    weights: (..., V) non-negative; a view with weight 0 or NaN, or NaN coordinates, is ignored.
    Returns (..., 3) world points; NaN where fewer than 2 views have positive weight.
    """
    xy = np.asarray(xy, dtype=np.float64)
    if xy.ndim < 2 or xy.shape[-1] != 2:
        raise ValueError(f"xy must have shape (..., V, 2), got {xy.shape}")
    V = xy.shape[-2]
    P = checked(P, "P", (V, 3, 4))
    w = checked(weights, "weights", xy.shape[:-1])
    lead = xy.shape[:-2]
    X = dlt_all(
        np.ascontiguousarray(xy.reshape(1, -1, V, 2)), np.ascontiguousarray(w.reshape(1, -1, V)), P
    )
    return X.reshape(*lead, 3)
