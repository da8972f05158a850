"""Synthetic skeletons for the behaviour tests, from simple geometry: COCO-17 joints (17, 3) in
metres, world frame z up, floor at z = 0.

Upright bodies come from stereopose.sim.motion.pose (adult proportions scaled by height); the
others are built from it: kneeling, squatting and sitting move the hips and legs and lower the
upper body rigidly; lying and falling rotate the whole body about the ankles.
"""

from __future__ import annotations

import numpy as np

from stereopose.sim.motion import SHIN, THIGH, pose
from stereopose.skeleton import (
    LEFT_ANKLE,
    LEFT_HIP,
    LEFT_KNEE,
    NUM_JOINTS,
    RIGHT_ANKLE,
    RIGHT_HIP,
    RIGHT_KNEE,
)
from stereopose.types import People3D

UPPER = list(range(RIGHT_HIP + 1))  # head, shoulders, arms, hips: moved together
ANKLE_Z = 0.07


def _axes(heading: float) -> tuple[np.ndarray, np.ndarray]:
    f = np.array([np.cos(heading), np.sin(heading), 0.0])
    left = np.array([-np.sin(heading), np.cos(heading), 0.0])
    return f, left


def rotate(J: np.ndarray, pivot: np.ndarray, axis: np.ndarray, angle: float) -> np.ndarray:
    """Joints rotated by angle (rad, right hand) about the line through pivot along axis."""
    k = axis / np.linalg.norm(axis)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    R = np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K
    return (J - pivot) @ R.T + pivot


def standing(height: float = 1.75, xy=(0.0, 0.0), heading: float = 0.0, **signals) -> np.ndarray:
    """An upright body; signals: pose()'s gait, phase, reach_left, reach_right, bend."""
    kw = {k: np.array([v], dtype=float) for k, v in signals.items()}
    return pose(height, np.array([xy], dtype=float), np.array([heading]), **kw)[0]


def _lowered(
    J: np.ndarray, hip_z: float, back_m: float = 0.0, heading: float = 0.0, lean: float = 0.0
) -> np.ndarray:
    """The upper body (head to hips) lowered so the hips are at hip_z, moved back_m backwards,
    then leaned forward by `lean` rad about the hip centre."""
    out = J.copy()
    f, left = _axes(heading)
    hips = 0.5 * (J[LEFT_HIP] + J[RIGHT_HIP])
    shift = np.array([0.0, 0.0, hip_z - hips[2]]) - back_m * f
    out[UPPER] = J[UPPER] + shift
    if lean:
        centre = 0.5 * (out[LEFT_HIP] + out[RIGHT_HIP])
        upper = list(range(LEFT_HIP))  # the hips stay where they are
        out[upper] = rotate(out[upper], centre, left, lean)
    return out


def _leg(out: np.ndarray, knee_j: int, ankle_j: int, knee, ankle) -> None:
    out[knee_j], out[ankle_j] = knee, ankle


def kneeling(
    height: float = 1.75,
    xy=(0.0, 0.0),
    heading: float = 0.0,
    one_knee: bool = False,
    lean: float = 0.0,
) -> np.ndarray:
    """Kneeling upright (thighs vertical, knees and shins on the floor); one_knee: the right
    foot forward, its thigh level (a half kneel); lean: the torso forward, rad."""
    f, _ = _axes(heading)
    thigh, shin = THIGH * height, SHIN * height
    J = _lowered(standing(height, xy, heading), ANKLE_Z + thigh, heading=heading, lean=lean)
    for hip_j, knee_j, ankle_j in (
        (LEFT_HIP, LEFT_KNEE, LEFT_ANKLE),
        (RIGHT_HIP, RIGHT_KNEE, RIGHT_ANKLE),
    ):
        hip = J[hip_j]
        if one_knee and hip_j == RIGHT_HIP:
            knee = hip + thigh * f
            ankle = knee.copy()
            ankle[2] = ANKLE_Z
            knee[2] = ANKLE_Z + shin
        else:
            knee = np.array([hip[0], hip[1], ANKLE_Z])
            ankle = knee - shin * f
        _leg(J, knee_j, ankle_j, knee, ankle)
    return J


def squatting(
    height: float = 1.75,
    xy=(0.0, 0.0),
    heading: float = 0.0,
    lean: float = 0.4,
    hip_z: float | None = None,
) -> np.ndarray:
    """A deep squat (or, given hip_z, a shallower one): hips low and back, knees forward, feet
    flat, torso leaning."""
    f, _ = _axes(heading)
    thigh, shin = THIGH * height, SHIN * height
    base = standing(height, xy, heading)
    ankles = {LEFT_ANKLE: base[LEFT_ANKLE].copy(), RIGHT_ANKLE: base[RIGHT_ANKLE].copy()}
    hip_z = ANKLE_Z + 0.35 * height * 0.55 if hip_z is None else hip_z
    J = _lowered(base, hip_z, back_m=0.25 * thigh, heading=heading, lean=lean)
    for hip_j, knee_j, ankle_j in (
        (LEFT_HIP, LEFT_KNEE, LEFT_ANKLE),
        (RIGHT_HIP, RIGHT_KNEE, RIGHT_ANKLE),
    ):
        ankle = ankles[ankle_j]
        ankle[2] = ANKLE_Z
        hip = J[hip_j]
        # the knee where the thigh and the shin meet, forward of the hip-ankle line
        d = ankle - hip
        dist = np.linalg.norm(d)
        u = d / dist
        a = (thigh**2 - shin**2 + dist**2) / (2 * dist)
        b = np.sqrt(max(thigh**2 - a**2, 0.0))
        n = f - (f @ u) * u
        n /= np.linalg.norm(n)
        _leg(J, knee_j, ankle_j, hip + a * u + b * n, ankle)
    return J


def sitting_chair(height: float = 1.75, xy=(0.0, 0.0), heading: float = 0.0) -> np.ndarray:
    """Sitting on a chair: thighs level, shins vertical, torso upright."""
    f, _ = _axes(heading)
    thigh, shin = THIGH * height, SHIN * height
    J = _lowered(standing(height, xy, heading), ANKLE_Z + shin, heading=heading)
    for hip_j, knee_j, ankle_j in (
        (LEFT_HIP, LEFT_KNEE, LEFT_ANKLE),
        (RIGHT_HIP, RIGHT_KNEE, RIGHT_ANKLE),
    ):
        knee = J[hip_j] + thigh * f
        ankle = knee.copy()
        ankle[2] = ANKLE_Z
        _leg(J, knee_j, ankle_j, knee, ankle)
    return J


def sitting_floor(height: float = 1.75, xy=(0.0, 0.0), heading: float = 0.0) -> np.ndarray:
    """Sitting on the floor, legs straight ahead, torso upright."""
    f, _ = _axes(heading)
    thigh, shin = THIGH * height, SHIN * height
    J = _lowered(standing(height, xy, heading), 0.1, heading=heading)
    for hip_j, knee_j, ankle_j in (
        (LEFT_HIP, LEFT_KNEE, LEFT_ANKLE),
        (RIGHT_HIP, RIGHT_KNEE, RIGHT_ANKLE),
    ):
        knee = J[hip_j] + thigh * f
        knee[2] = 0.1
        ankle = knee + shin * f
        ankle[2] = ANKLE_Z
        _leg(J, knee_j, ankle_j, knee, ankle)
    return J


def tipped(J: np.ndarray, heading: float, angle: float, sideways: bool = False) -> np.ndarray:
    """An upright body rotated about its ankles by angle (rad): backwards (or to its left
    side); pi / 2 lays it flat."""
    f, left = _axes(heading)
    pivot = 0.5 * (J[LEFT_ANKLE] + J[RIGHT_ANKLE])
    pivot[2] = ANKLE_Z
    axis = -f if sideways else left
    return rotate(J, pivot, axis, -angle if not sideways else angle)


def lying(
    height: float = 1.75, xy=(0.0, 0.0), heading: float = 0.0, sideways: bool = False
) -> np.ndarray:
    """Lying flat on the back (or on the side), feet at xy; the lowest joint on the floor."""
    J = tipped(standing(height, xy, heading), heading, np.pi / 2, sideways)
    J[:, 2] += 0.03 - J[:, 2].min()
    return J


def people(
    frame: int,
    bodies: dict[int, np.ndarray],
    t: float | None = None,
    predicted: dict[int, bool] | None = None,
) -> People3D:
    """People3D of one frame from {id: joints (17, 3)}."""
    ids = sorted(bodies)
    P = len(ids)
    J = np.array([bodies[i] for i in ids]).reshape(P, NUM_JOINTS, 3)
    conf = np.where(np.isfinite(J).all(-1), 0.9, 0.0)
    pred = np.array([bool((predicted or {}).get(i, False)) for i in ids], dtype=bool)
    return People3D(
        frame,
        J,
        conf,
        np.array(ids, dtype=np.int64),
        np.full((P, NUM_JOINTS), 1.0),
        np.full((P, NUM_JOINTS), 3),
        np.zeros((P, 3), dtype=np.int64),
        predicted=pred,
        t=t,
    )


def noisy(
    J: np.ndarray, rng: np.random.Generator, sigma_m: float = 0.02, missing: float = 0.0
) -> np.ndarray:
    """Joints with Gaussian noise and a share of them missing (NaN)."""
    out = J + rng.normal(0.0, sigma_m, J.shape)
    out[rng.random(J.shape[0]) < missing] = np.nan
    return out
