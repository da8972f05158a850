"""A camera's pose from 2D-3D correspondences, and a camera with a new pose: what the rig
from surveyed points, from people and a camera's refinement share. OpenCV only (no scipy):
`serve` places a drifted camera again with it on an install without the calibration extra."""

from __future__ import annotations

from collections.abc import Iterable

import cv2
import numpy as np

from stereopose.types import Camera

__all__ = ["camera_with_pose", "intrinsics_row", "pose_change", "rig_poses", "robust_pnp"]


def intrinsics_row(cam: Camera) -> np.ndarray:
    """(8,) fx, fy, cx, cy, k1, k2, p1, p2 of a camera (a k3 is not used by this model)."""
    K, d = cam.matrix, np.zeros(4)
    d[: min(4, cam.distortions.size)] = cam.distortions[:4]
    return np.array([K[0, 0], K[1, 1], K[0, 2], K[1, 2], *d])


def rig_poses(cameras: Iterable[Camera]) -> np.ndarray:
    """(C, 6) each camera's pose (Rodrigues vector, translation; world -> camera), in order."""
    return np.stack([np.concatenate([c.rotation, c.translation]) for c in cameras])


def pose_change(old: Camera, new: Camera) -> tuple[float, float]:
    """How far a camera placed again moved: (turned degrees, moved metres of its centre)."""
    turned = float(np.degrees(np.linalg.norm(cv2.Rodrigues(new.R @ old.R.T)[0])))
    return turned, float(np.linalg.norm(new.center - old.center))


def camera_with_pose(cam: Camera, pose: np.ndarray) -> Camera:
    """The camera with the pose (6,) (Rodrigues vector, translation; world -> camera)."""
    pose = np.asarray(pose, dtype=np.float64)
    return Camera(cam.name, cam.size, cam.matrix, cam.distortions, pose[:3], pose[3:], cam.fisheye)


def robust_pnp(
    obj: np.ndarray,
    img: np.ndarray,
    K: np.ndarray,
    dist: np.ndarray | None,
    max_px: float,
    iterations: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """The pose most points agree with (SQPnP in RANSAC, then Levenberg-Marquardt on them).

    obj: (N, 3) world points; img: (N, 2) their pixels in the image of K and dist (K the
    identity and dist None for normalised coordinates); max_px: an agreeing point's largest
    residual, in img's units. Returns (rvec (3, 1), tvec (3, 1), inlier indices), or None."""
    ok, r, t, inl = cv2.solvePnPRansac(
        obj,
        img,
        K,
        dist,
        reprojectionError=max_px,
        iterationsCount=iterations,
        confidence=0.9999,
        flags=cv2.SOLVEPNP_SQPNP,
    )
    if not ok or inl is None or len(inl) < 4:
        return None
    keep = np.asarray(inl, dtype=np.intp).ravel()
    r, t = cv2.solvePnPRefineLM(obj[keep], img[keep], K, dist, r, t)
    return r, t, keep
