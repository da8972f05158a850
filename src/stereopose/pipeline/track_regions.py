"""The tracks' way back to detection: each tracked person's box in a camera at the next step's
time, for the regions where detection.regional looks (the one loop of the data flow, through
the frame loop); and, from the site, how small a worker can look in each camera where he
matters, for its scans."""

from __future__ import annotations

from collections.abc import Collection, Sequence

import numpy as np

from stereopose.geometry.camera import project, world_to_camera
from stereopose.types import Camera, People3D, Rig
from stereopose.zones import Zone
from stereopose.zones.hazard import Hazards

AHEAD_MAX_S = 1.0  # a track is moved on by its velocity for at most this long
NEAR_M = 0.5  # a person with a joint nearer the camera's plane than this has no sane box
HEAD_ROOM = 0.12  # of the joints' height above the top joint (the eyes): the top of the head
FOOT_ROOM = 0.05  # below the ankles
WORKER_M = 1.6  # the smallest worker the scans are planned for, metres tall
REACH_M = 1.0  # around a zone, beyond its margin, where a worker matters (he walks in from it)
GRID = 11  # places per side of each zone's grown box where a worker is put


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
    ok = np.asarray(np.isfinite(px).all(axis=2))  # (P, 17)
    nearest = np.where(np.isfinite(depth), depth, np.inf).min(axis=1)
    keep = ok.any(axis=1) & (nearest >= NEAR_M)
    if not keep.any():
        return np.zeros((0, 4))
    px, ok = px[keep], ok[keep, :, None]
    lo = np.where(ok, px, np.inf).min(axis=1)  # (K, 2)
    hi = np.where(ok, px, -np.inf).max(axis=1)
    h = np.maximum(np.maximum(hi[:, 1] - lo[:, 1], hi[:, 0] - lo[:, 0]), 1.0)
    return np.column_stack(
        [lo[:, 0], lo[:, 1] - HEAD_ROOM * h, hi[:, 0], hi[:, 1] + FOOT_ROOM * h]
    ).astype(np.float64)


def held_cameras(
    hazards: Hazards | None,
    people: People3D | None,
    rig: Rig,
    names: Collection[str],
    t: float,
    fps: float,
    ahead_s: float = 0.0,
) -> set[str]:
    """The cameras of `names` that must detect at time t whatever their people's pace (the
    carried steps' rule near hazards, detection.carry): those that see a tracked person near
    an energized zone by t (zones.hazard), a hand moving at the hazards' speed from the pose
    known for as long as from its time to t (at least one step, and at least ahead_s); every
    camera while no pose is known yet; none without hazards."""
    if hazards is None or not hazards:
        return set()
    if people is None:
        return set(names)
    ahead = max(t - people.time(fps), 1.0 / fps, ahead_s)
    near = hazards.near(people.joints, ahead)
    if not near.any():
        return set()
    return cameras_seeing(people, rig, near) & set(names)


def cameras_seeing(people: People3D, rig: Rig, which: np.ndarray) -> set[str]:
    """The cameras of `rig` that see any of the people picked by `which` (P,) bool: those
    whose detection was used for him (People3D.detections, in the rig's order) and those into
    whose picture a joint of his projects (in front of the camera), so that a person only
    predicted, or missed by a camera's matching, is still seen where he stands."""
    picked = np.flatnonzero(np.asarray(which, dtype=bool))
    if not picked.size:
        return set()
    det = people.detections[picked]
    out = {n for c, n in enumerate(rig.names) if c < det.shape[1] and (det[:, c] >= 0).any()}
    J = people.joints[picked].reshape(-1, 3)
    J = J[np.isfinite(J).all(axis=1)]
    if not len(J):
        return out
    for camera in rig:
        if camera.name in out:
            continue
        px = project(J, camera)  # NaN behind the camera
        w, h = camera.size
        with np.errstate(invalid="ignore"):
            inside = (px[:, 0] >= 0) & (px[:, 0] < w) & (px[:, 1] >= 0) & (px[:, 1] < h)
        if inside.any():
            out.add(camera.name)
    return out


def watched_heights(rig: Rig, zones: Sequence[Zone]) -> dict[str, float]:
    """Per camera, how tall (its pixels) the smallest worker looks anywhere he matters: one
    WORKER_M tall standing on a grid over each zone's box grown by its margin and REACH_M,
    where his feet or his head fall inside the picture. inf: no such place in the camera's
    view; no zones: {} (nothing known: the scans look everywhere)."""
    places = []
    for z in zones:
        grow = float(z.margin_m or 0.0) + REACH_M
        lo, hi = z.polygon.min(axis=0) - grow, z.polygon.max(axis=0) + grow
        gx, gy = np.meshgrid(np.linspace(lo[0], hi[0], GRID), np.linspace(lo[1], hi[1], GRID))
        places.append(np.column_stack([gx.ravel(), gy.ravel()]))
    if not places:
        return {}
    floor = np.concatenate(places)
    feet = np.column_stack([floor, np.zeros(len(floor))])
    heads = feet + np.array([0.0, 0.0, WORKER_M])
    out = {}
    for camera in rig:
        a, b = project(feet, camera), project(heads, camera)
        w, h = camera.size

        def inside(p: np.ndarray, w: float = w, h: float = h) -> np.ndarray:
            return (p[:, 0] >= 0) & (p[:, 0] < w) & (p[:, 1] >= 0) & (p[:, 1] < h)

        seen = np.isfinite(a).all(axis=1) & np.isfinite(b).all(axis=1) & (inside(a) | inside(b))
        tall = np.linalg.norm(b - a, axis=1)
        out[camera.name] = float(tall[seen].min()) if seen.any() else float("inf")
    return out


def watched_shares(rig: Rig, zones: Sequence[Zone]) -> dict[str, float]:
    """watched_heights as a share of each camera's frame height (the calibration's), for
    frames of any size of that camera (a substream's): {} with no zones."""
    return {n: v / float(rig[n].size[1]) for n, v in watched_heights(rig, zones).items()}
