"""Projection with OpenCV lens distortion, and undistortion of keypoints.

Frames: world (metres, z up) -> camera (OpenCV: x right, y down, z forward) -> normalised image
coordinates (x/z, y/z) -> distorted normalised -> pixels.
"""

from __future__ import annotations

import cv2
import numpy as np

from stereopose.arrays import checked
from stereopose.geometry._kernels import project_all
from stereopose.types import Camera, Rig

# stop once the reprojected point is within 1e-8 px of the observed one, or after 30 steps
UNDISTORT_STOP = (1e-8, 30)
_UNDISTORT_CRITERIA = (
    cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS,
    UNDISTORT_STOP[1],
    UNDISTORT_STOP[0],
)


def _check_last(a: np.ndarray, n: int, what: str) -> np.ndarray:
    a = np.asarray(a, dtype=np.float64)
    if a.ndim == 0 or a.shape[-1] != n:
        raise ValueError(f"{what} must have shape (..., {n}), got {a.shape}")
    return a


def homogeneous(x: np.ndarray) -> np.ndarray:
    """(..., n) -> (..., n + 1) with a trailing 1."""
    return np.concatenate([x, np.ones((*x.shape[:-1], 1))], axis=-1)


def world_to_camera(points_world: np.ndarray, camera: Camera) -> np.ndarray:
    """(..., 3) world points (m) -> (..., 3) points in the camera frame (m)."""
    X = _check_last(points_world, 3, "points_world")
    return X @ camera.R.T + camera.translation


def distort(xy: np.ndarray, distortions: np.ndarray) -> np.ndarray:
    """Apply OpenCV distortion to (..., 2) ideal normalised coordinates.

    distortions: (4,) k1 k2 p1 p2 or (5,) with k3, or one row per camera (C, 4 or 5) for
    points (..., C, 2) of C cameras. Returns observed normalised coordinates.
    """
    xy = _check_last(xy, 2, "xy")
    d = np.asarray(distortions, dtype=np.float64)
    k1, k2, p1, p2 = d[..., 0], d[..., 1], d[..., 2], d[..., 3]
    k3 = d[..., 4] if d.shape[-1] > 4 else 0.0
    x, y = xy[..., 0], xy[..., 1]
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
    return np.stack([xd, yd], axis=-1)


def normalized_to_pixels(xy: np.ndarray, K: np.ndarray) -> np.ndarray:
    """(..., 2) normalised coordinates -> pixels with intrinsics K (3, 3), or one per camera
    (C, 3, 3) for points (..., C, 2) of C cameras."""
    x, y = xy[..., 0], xy[..., 1]
    fx, g, cx, fy, cy = K[..., 0, 0], K[..., 0, 1], K[..., 0, 2], K[..., 1, 1], K[..., 1, 2]
    return np.stack([fx * x + g * y + cx, fy * y + cy], axis=-1)


def project(points_world: np.ndarray, camera: Camera) -> np.ndarray:
    """Project (..., 3) world points (m) to (..., 2) distorted pixels of `camera`.

    Points at or behind the camera (z <= 1 mm) give NaN, as do NaN inputs.
    """
    xy = project_to_cameras(points_world, camera.P[None])[..., 0, :]
    return normalized_to_pixels(distort(xy, camera.distortions), camera.matrix)


def project_to_rig(points_world: np.ndarray, rig: Rig) -> np.ndarray:
    """Project (..., 3) world points (m) into every camera of `rig` at once: (..., C, 2)
    distorted pixels, as `project` gives camera by camera (NaN behind a camera)."""
    P = np.stack([c.P for c in rig])
    K = np.stack([c.matrix for c in rig])
    dist = rig.lenses[1]
    return normalized_to_pixels(distort(project_to_cameras(points_world, P), dist), K)


def project_to_cameras(points_world: np.ndarray, P: np.ndarray) -> np.ndarray:
    """Project (..., 3) world points into each of C cameras [R | t] (C, 3, 4) at once.

    Returns (..., C, 2) ideal normalised coordinates; NaN behind a camera or for NaN input.
    """
    X = _check_last(points_world, 3, "points_world")
    P = checked(P, "P", ("C", 3, 4))
    out = project_all(np.ascontiguousarray(X.reshape(-1, 1, 3)), P)
    return out.reshape(*X.shape[:-1], P.shape[0], 2)


def undistort_normalized(pixels: np.ndarray, camera: Camera) -> np.ndarray:
    """(..., 2) distorted pixels -> (..., 2) ideal normalised coordinates (NaN stays NaN)."""
    uv = _check_last(pixels, 2, "pixels")
    if uv.size == 0:
        return uv.copy()
    out = cv2.undistortPoints(
        np.ascontiguousarray(uv.reshape(-1, 1, 2)),
        camera.matrix,
        camera.distortions,
        criteria=_UNDISTORT_CRITERIA,
    )
    return out.reshape(uv.shape)


def undistort_pixels(pixels: np.ndarray, camera: Camera) -> np.ndarray:
    """(..., 2) distorted pixels -> (..., 2) pixels of the ideal (undistorted) pinhole image."""
    return normalized_to_pixels(undistort_normalized(pixels, camera), camera.matrix)
