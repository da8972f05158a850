"""The tracks' way back to detection: each tracked person's box in a camera at the next step's
time, for the regions where detection.regional looks (the one loop of the data flow, through
the frame loop)."""

from __future__ import annotations

import numpy as np

from stereopose.geometry.camera import project, world_to_camera
from stereopose.types import Camera, People3D

AHEAD_MAX_S = 1.0  # a track is moved on by its velocity for at most this long
NEAR_M = 0.5  # a person with a joint nearer the camera's plane than this has no sane box
HEAD_ROOM = 0.12  # of the joints' height above the top joint (the eyes): the top of the head
FOOT_ROOM = 0.05  # below the ankles


def track_boxes(people: People3D, camera: Camera, t: float) -> np.ndarray:
    """Each person's box (N, 4) x1 y1 x2 y2 in `camera`'s calibration pixels at time t: his
    joints (metres, world) moved along his floor velocity from his own time to t (at most
    AHEAD_MAX_S), projected, with room for the head and the feet. A person with no joint in
    front of the camera, or with one nearer its plane than NEAR_M (his projection blows up:
    a person beside or behind the camera), gives no box."""
    if not len(people):
        return np.zeros((0, 4))
    dt = 0.0 if people.t is None else float(np.clip(t - people.t, 0.0, AHEAD_MAX_S))
    J = np.array(people.joints, dtype=np.float64)
    v = np.nan_to_num(np.asarray(people.velocity, dtype=np.float64))
    J[..., :2] += v[:, None, :] * dt
    px = project(J, camera)  # (P, 17, 2), NaN behind the camera or where a joint is missing
    depth = world_to_camera(J, camera)[..., 2]  # (P, 17), NaN where a joint is missing
    out = []
    for p, z in zip(px, depth, strict=True):
        ok = np.isfinite(p).all(axis=1)
        if not ok.any() or np.nanmin(np.where(np.isfinite(z), z, np.inf)) < NEAR_M:
            continue
        x1, y1 = p[ok].min(axis=0)
        x2, y2 = p[ok].max(axis=0)
        h = max(y2 - y1, x2 - x1, 1.0)
        out.append((x1, y1 - HEAD_ROOM * h, x2, y2 + FOOT_ROOM * h))
    return np.asarray(out, dtype=np.float64).reshape(-1, 4)
