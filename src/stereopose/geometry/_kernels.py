"""Compiled loops of the geometry (numba): the one pinhole projection, the one DLT solve,
undistortion. Called through the checked wrappers of geometry.camera and
geometry.triangulation, and from the compiled loops of the other domains.

Division follows NumPy (x / 0 is inf or NaN, never an error). Compiled once per machine,
cached beside this module.
"""

from __future__ import annotations

import numpy as np
from numba import njit

# a point this close to a camera's plane (or behind it) does not project
MIN_DEPTH_M = 1e-3

_JIT = {"cache": True, "error_model": "numpy", "nogil": True}


@njit(**_JIT)
def pinhole(P: np.ndarray, c: int, x0: float, x1: float, x2: float) -> tuple[float, float, bool]:
    """World point (x0, x1, x2) in camera c of P (C, 3, 4) [R | t]: ideal normalised (u, v),
    and whether it lies in front of the camera (u, v NaN when not)."""
    zc = P[c, 2, 0] * x0 + P[c, 2, 1] * x1 + P[c, 2, 2] * x2 + P[c, 2, 3]
    if not (zc > MIN_DEPTH_M):
        return np.nan, np.nan, False
    u = (P[c, 0, 0] * x0 + P[c, 0, 1] * x1 + P[c, 0, 2] * x2 + P[c, 0, 3]) / zc
    v = (P[c, 1, 0] * x0 + P[c, 1, 1] * x1 + P[c, 1, 2] * x2 + P[c, 1, 3]) / zc
    return u, v, True


@njit(**_JIT)
def dist3(X: np.ndarray, g: int, a: int, b: int) -> float:
    """Distance between joints a and b of person g of X (G, J, 3)."""
    dx = X[g, a, 0] - X[g, b, 0]
    dy = X[g, a, 1] - X[g, b, 1]
    dz = X[g, a, 2] - X[g, b, 2]
    return np.sqrt(dx * dx + dy * dy + dz * dz)


@njit(**_JIT)
def dlt_point(
    xy: np.ndarray, w: np.ndarray, use: np.ndarray, P: np.ndarray, out: np.ndarray
) -> None:
    """Weighted DLT of one point from the views c where use[c] (C,), w[c] > 0 and xy[c] (C, 2)
    is finite; writes out (3,), NaN when singular (fewer than two views). Least squares with
    the homogeneous coordinate fixed to 1: the 3 x 3 normal equations solved by the adjugate."""
    N = np.zeros((4, 4))
    C = xy.shape[0]
    for c in range(C):
        if not use[c]:
            continue
        wc = w[c]
        if not (wc > 0.0):
            continue
        x, y = xy[c, 0], xy[c, 1]
        if not (np.isfinite(x) and np.isfinite(y)):
            continue
        w2 = wc * wc
        for i in range(4):
            r1i = x * P[c, 2, i] - P[c, 0, i]
            r2i = y * P[c, 2, i] - P[c, 1, i]
            for k in range(4):
                r1k = x * P[c, 2, k] - P[c, 0, k]
                r2k = y * P[c, 2, k] - P[c, 1, k]
                N[i, k] += w2 * (r1i * r1k + r2i * r2k)
    a, b, cc, r0 = N[0, 0], N[0, 1], N[0, 2], N[0, 3]
    d, f, r1 = N[1, 1], N[1, 2], N[1, 3]
    g, r2 = N[2, 2], N[2, 3]
    A = d * g - f * f
    B = cc * f - b * g
    Cc = b * f - cc * d
    D = a * g - cc * cc
    E = b * cc - a * f
    F = a * d - b * b
    det = a * A + b * B + cc * Cc
    tr = abs(a + d + g)
    if not (abs(det) > 1e-12 * tr * tr * tr):
        out[0] = out[1] = out[2] = np.nan
        return
    inv = -1.0 / det
    out[0] = (A * r0 + B * r1 + Cc * r2) * inv
    out[1] = (B * r0 + D * r1 + E * r2) * inv
    out[2] = (Cc * r0 + E * r1 + F * r2) * inv


@njit(**_JIT)
def dlt_all(xy: np.ndarray, w: np.ndarray, P: np.ndarray) -> np.ndarray:
    """Weighted DLT (G, J, 3) of every point from all its views: xy (G, J, C, 2), w (G, J, C);
    NaN with fewer than two views."""
    G, J, C = w.shape
    X = np.empty((G, J, 3))
    use = np.ones(C, dtype=np.bool_)
    for g in range(G):
        for j in range(J):
            dlt_point(xy[g, j], w[g, j], use, P, X[g, j])
    return X


@njit(**_JIT)
def view_errors(
    X: np.ndarray, xy: np.ndarray, P: np.ndarray, focal: np.ndarray, out: np.ndarray
) -> None:
    """Pixel distance (C,) between X (3,) reprojected and each view xy (C, 2) (NaN where either
    is missing or X is behind the camera); focal (C,) converts normalised units to pixels."""
    C = xy.shape[0]
    for c in range(C):
        u, v, front = pinhole(P, c, X[0], X[1], X[2])
        if not front:
            out[c] = np.nan
            continue
        du, dv = u - xy[c, 0], v - xy[c, 1]
        out[c] = np.sqrt(du * du + dv * dv) * focal[c]


@njit(**_JIT)
def project_all(X: np.ndarray, P: np.ndarray) -> np.ndarray:
    """Points (T, J, 3) projected into every camera (C, 3, 4): (T, J, C, 2) ideal normalised
    coordinates, NaN behind a camera or for NaN input."""
    T, J, C = X.shape[0], X.shape[1], P.shape[0]
    out = np.full((T, J, C, 2), np.nan)
    for t in range(T):
        for j in range(J):
            for c in range(C):
                u, v, front = pinhole(P, c, X[t, j, 0], X[t, j, 1], X[t, j, 2])
                if front:
                    out[t, j, c, 0] = u
                    out[t, j, c, 1] = v
    return out


@njit(**_JIT)
def in_view(
    X: np.ndarray, P: np.ndarray, lo: np.ndarray, hi: np.ndarray, min_joints: int
) -> np.ndarray:
    """(G, C) whether >= min_joints joints of each person (G, J, 3) project inside each
    camera's image bounds lo, hi (C, 2) (ideal normalised coordinates), in front of it."""
    G, J = X.shape[0], X.shape[1]
    C = P.shape[0]
    out = np.zeros((G, C), dtype=np.bool_)
    for g in range(G):
        for c in range(C):
            n = 0
            for j in range(J):
                u, v, front = pinhole(P, c, X[g, j, 0], X[g, j, 1], X[g, j, 2])
                if front and lo[c, 0] <= u <= hi[c, 0] and lo[c, 1] <= v <= hi[c, 1]:
                    n += 1
            out[g, c] = n >= min_joints
    return out


@njit(**_JIT)
def undistort(
    uv: np.ndarray,
    camera: np.ndarray,
    intrinsics: np.ndarray,
    dist: np.ndarray,
    eps_px: float,
    max_iter: int,
) -> np.ndarray:
    """Distorted pixels (M, 2) of the cameras `camera` (M,) -> ideal normalised coordinates
    (M, 2), NaN staying NaN: OpenCV's iterative undistortPoints (the same fixed-point
    iteration, stopped once the point reprojects within eps_px or after max_iter steps).
    intrinsics: (C, 4) fx, fy, cx, cy; dist: (C, 5) k1 k2 p1 p2 k3."""
    M = uv.shape[0]
    out = np.empty((M, 2))
    for m in range(M):
        u, v = uv[m, 0], uv[m, 1]
        if not (np.isfinite(u) and np.isfinite(v)):
            out[m, 0] = out[m, 1] = np.nan
            continue
        c = camera[m]
        fx, fy, cx, cy = intrinsics[c, 0], intrinsics[c, 1], intrinsics[c, 2], intrinsics[c, 3]
        k1, k2, p1, p2, k3 = dist[c, 0], dist[c, 1], dist[c, 2], dist[c, 3], dist[c, 4]
        x0 = (u - cx) / fx
        y0 = (v - cy) / fy
        x, y = x0, y0
        for _ in range(max_iter):
            r2 = x * x + y * y
            icdist = 1.0 / (1.0 + ((k3 * r2 + k2) * r2 + k1) * r2)
            if icdist < 0.0:
                x, y = x0, y0
                break
            dx = 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
            dy = p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
            x = (x0 - dx) * icdist
            y = (y0 - dy) * icdist
            r2 = x * x + y * y
            cdist = 1.0 + ((k3 * r2 + k2) * r2 + k1) * r2
            xd = x * cdist + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
            yd = y * cdist + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
            ex = xd * fx + cx - u
            ey = yd * fy + cy - v
            if np.sqrt(ex * ex + ey * ey) < eps_px:
                break
        out[m, 0], out[m, 1] = x, y
    return out
