"""How far to trust a rig from people: each camera's fit on the recordings it was calibrated
on and on one it was not, and whether joints that are points in every view hold it.

A COCO shoulder or hip is a point on the body's surface: the detector puts it where the body's
outline is, which moves with the view, so cameras on opposite sides see two different points.
The nose, eyes, ears, wrists and ankles are nearly points, the same in every view. A camera
whose pose rests mostly on shoulders and hips can fit its own recording and still sit off.
"""

from __future__ import annotations

import numpy as np

from stereopose.calibration.bundle import project_px
from stereopose.calibration.people_match import MIN_CONF, Views, triangulate_groups

__all__ = [
    "FIT_CONF",
    "MIN_POINT_LIKE",
    "POINT_LIKE",
    "camera_fit_px",
    "fit_px",
    "point_like_joints",
    "thin_warnings",
]

POINT_LIKE = (0, 1, 2, 3, 4, 9, 10, 15, 16)  # nose, eyes, ears, wrists, ankles (COCO)
MIN_POINT_LIKE = 300  # a camera's observations of such joints, at least, to trust its pose
FIT_CONF = 0.5  # the joints a fit is measured on: this confident or more


def _errors(
    views: Views, groups: list[dict[int, int]], poses: np.ndarray, intr: np.ndarray
) -> list[np.ndarray]:
    """Per camera, the pixel errors of its confident joints, each group triangulated from all
    its cameras."""
    C = len(poses)
    X = triangulate_groups(views, groups, poses, np.ones(C, dtype=bool))
    errs: list[list[np.ndarray]] = [[] for _ in range(C)]
    for g, members in enumerate(groups):
        ok = np.isfinite(X[g, :, 0])
        if not ok.any():
            continue
        for c, k in members.items():
            kp = views.det[k][2]
            use = ok & (kp[:, 2] >= FIT_CONF)
            if not use.any():
                continue
            n = int(use.sum())
            uv, _ = project_px(
                np.repeat(poses[c : c + 1], n, 0), np.repeat(intr[c : c + 1], n, 0), X[g, use]
            )
            errs[c].append(np.linalg.norm(uv - kp[use, :2], axis=1))
    return [np.concatenate(e) if e else np.zeros(0) for e in errs]


def fit_px(
    views: Views, groups: list[dict[int, int]], poses: np.ndarray, intr: np.ndarray
) -> float:
    """Median pixel error of every group's confident joints, triangulated with poses."""
    e = np.concatenate(_errors(views, groups, poses, intr))
    return float(np.median(e)) if e.size else float("inf")


def camera_fit_px(
    views: Views, groups: list[dict[int, int]], poses: np.ndarray, intr: np.ndarray
) -> dict[str, float]:
    """Each camera's median pixel error of its confident joints (NaN: none)."""
    return {
        n: float(np.median(e)) if e.size else float("nan")
        for n, e in zip(views.cameras, _errors(views, groups, poses, intr), strict=True)
    }


def point_like_joints(
    views: Views, groups: list[dict[int, int]], pid: np.ndarray, names: list[str]
) -> dict[str, int]:
    """Each camera's observations of point-like joints among the adjustment's points."""
    count = dict.fromkeys(names, 0)
    for g, j in zip(*np.nonzero(pid >= 0), strict=True):
        if j not in POINT_LIKE:
            continue
        for c, k in groups[g].items():
            if views.det[k][2][j, 2] >= MIN_CONF:
                count[names[c]] += 1
    return count


def thin_warnings(point_like: dict[str, int], least: int = MIN_POINT_LIKE) -> list[str]:
    """A warning for each camera held by fewer than `least` point-like joints."""
    return [
        f"camera {n}: only {k} observations of joints that are points in every view (nose, "
        "eyes, ears, wrists, ankles) hold it; its pose rests on shoulders and hips, whose "
        "detected place moves with the view: have people walk nearer it, facing it and "
        "across its view"
        for n, k in point_like.items()
        if k < least
    ]
