"""Epipolar geometry between calibrated cameras."""

from __future__ import annotations

import numpy as np

from stereopose.geometry.camera import homogeneous
from stereopose.types import Camera, Rig


def skew(v: np.ndarray) -> np.ndarray:
    """(3,) vector -> (3, 3) cross-product matrix [v]_x."""
    x, y, z = np.asarray(v, dtype=np.float64)
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def essential_matrix(cam_a: Camera, cam_b: Camera) -> np.ndarray:
    """E (3, 3) with x_b^T E x_a = 0 for ideal normalised homogeneous points x_a, x_b."""
    R_ab = cam_b.R @ cam_a.R.T
    t_ab = cam_b.translation - R_ab @ cam_a.translation
    return skew(t_ab) @ R_ab


def fundamental_matrix(cam_a: Camera, cam_b: Camera) -> np.ndarray:
    """F (3, 3) with u_b^T F u_a = 0 for undistorted homogeneous pixels u_a, u_b.

    The line of u_a in camera b is l_b = F u_a (undistorted pixels of camera b).
    """
    E = essential_matrix(cam_a, cam_b)
    F = np.linalg.inv(cam_b.matrix).T @ E @ np.linalg.inv(cam_a.matrix)
    return F / np.linalg.norm(F)


def essential_matrices(rig: Rig) -> np.ndarray:
    """(C, C, 3, 3): E[a, b] maps normalised points of camera a to lines in camera b."""
    C = len(rig)
    E = np.zeros((C, C, 3, 3))
    for a in range(C):
        for b in range(C):
            if a != b:
                E[a, b] = essential_matrix(rig[a], rig[b])
    return E


def point_line_distance(points: np.ndarray, lines: np.ndarray) -> np.ndarray:
    """Distance of (..., 2) points to (..., 3) lines (a, b, c) with a x + b y + c = 0."""
    num = lines[..., 0] * points[..., 0] + lines[..., 1] * points[..., 1] + lines[..., 2]
    return np.abs(num) / np.hypot(lines[..., 0], lines[..., 1])


def symmetric_epipolar_distance(xa: np.ndarray, xb: np.ndarray, E: np.ndarray) -> np.ndarray:
    """Symmetric point-to-epipolar-line distance of matching (..., 2) points.

    xa, xb: (..., 2) in the coordinates E relates (normalised for an essential matrix, pixels
    for a fundamental matrix), broadcast against each other; E: (3, 3) with xb^T E xa = 0.
    Returns (...,) the mean of the distance of xb to E xa and of xa to E^T xb.
    """
    ha, hb = homogeneous(xa), homogeneous(xb)
    lb = ha @ E.T
    la = hb @ E
    return 0.5 * (point_line_distance(xb, lb) + point_line_distance(xa, la))
