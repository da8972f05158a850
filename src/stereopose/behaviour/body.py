"""The geometry of one skeleton, on its joints as plain (x, y, z) tuples (None: missing): 17
points are faster in plain Python than through many small NumPy calls.

World frame: metres, z up; joints are COCO-17 (stereopose.skeleton). Angles in degrees.
"""

from __future__ import annotations

import math

import numpy as np

from stereopose.skeleton import (
    FACE,
    LEFT_ANKLE,
    LEFT_EAR,
    LEFT_ELBOW,
    LEFT_HIP,
    LEFT_KNEE,
    LEFT_SHOULDER,
    LEFT_WRIST,
    NUM_JOINTS,
    RIGHT_ANKLE,
    RIGHT_EAR,
    RIGHT_ELBOW,
    RIGHT_HIP,
    RIGHT_KNEE,
    RIGHT_SHOULDER,
    RIGHT_WRIST,
)

HEAD = (*FACE, LEFT_EAR, RIGHT_EAR)
HIPS = (LEFT_HIP, RIGHT_HIP)
SHOULDERS = (LEFT_SHOULDER, RIGHT_SHOULDER)
WRISTS = (LEFT_WRIST, RIGHT_WRIST)
LEGS = ((LEFT_HIP, LEFT_KNEE, LEFT_ANKLE), (RIGHT_HIP, RIGHT_KNEE, RIGHT_ANKLE))
LATERAL_PAIRS = (
    (LEFT_KNEE, RIGHT_KNEE),
    (LEFT_ANKLE, RIGHT_ANKLE),
    (LEFT_ELBOW, RIGHT_ELBOW),
    (LEFT_EAR, RIGHT_EAR),
)

Point = tuple[float, float, float]


def points(J: np.ndarray) -> list[Point | None]:
    """The 17 joints (17, 3) as (x, y, z) tuples, None where any coordinate is missing (NaN);
    a ValueError for another shape."""
    J = np.asarray(J, dtype=np.float64)
    if J.shape != (NUM_JOINTS, 3):
        raise ValueError(f"joints must have shape ({NUM_JOINTS}, 3), got {J.shape}")
    ok: list[bool] = np.asarray(np.isfinite(J).all(-1)).tolist()
    return [(x, y, z) if k else None for (x, y, z), k in zip(J.tolist(), ok, strict=True)]


def known(pts: list[Point | None], idx: tuple[int, ...]) -> list[Point]:
    """The joints idx that are known."""
    return [p for i in idx if (p := pts[i]) is not None]


def mean_z(pts: list[Point | None], idx: tuple[int, ...]) -> float:
    """The mean height of the joints idx that are known (NaN: none)."""
    z = [p[2] for p in known(pts, idx)]
    return sum(z) / len(z) if z else math.nan


def centre(pts: list[Point | None], idx: tuple[int, ...]) -> Point | None:
    """The mean point of the joints idx that are known (None: none)."""
    got = known(pts, idx)
    if not got:
        return None
    n = len(got)
    return (sum(p[0] for p in got) / n, sum(p[1] for p in got) / n, sum(p[2] for p in got) / n)


def sub(a: Point, b: Point) -> Point:
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


def angle_to_vertical(v: Point | None) -> float:
    """The angle of the line along v to the vertical, 0 to 90 degrees (NaN: no v)."""
    if v is None:
        return math.nan
    n = math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
    if not math.isfinite(n) or n < 1e-6:
        return math.nan
    return math.degrees(math.acos(min(1.0, abs(v[2]) / n)))


def lateral(pts: list[Point | None]) -> Point | None:
    """The body's right -> left unit vector from a pair of side joints (knees, ankles, elbows,
    ears), None when no pair is known."""
    for left, right in LATERAL_PAIRS:
        a, b = pts[left], pts[right]
        if a is not None and b is not None:
            v = sub(a, b)
            n = math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
            if n > 0.1:
                return (v[0] / n, v[1] / n, v[2] / n)
    return None


def torso_vector(pts: list[Point | None]) -> Point | None:
    """Hip centre -> shoulder centre (None: cannot be told). Both centres when all four joints
    are known, else one side's hip and shoulder; else a hip and a shoulder of opposite sides,
    less their sideways part (the body's left-right axis from another pair of joints); else
    the hips' centre -> the head's."""
    hips, shoulders = centre(pts, HIPS), centre(pts, SHOULDERS)
    if all(pts[i] is not None for i in HIPS + SHOULDERS) and hips and shoulders:
        return sub(shoulders, hips)
    for hip, shoulder in ((LEFT_HIP, LEFT_SHOULDER), (RIGHT_HIP, RIGHT_SHOULDER)):
        h, s = pts[hip], pts[shoulder]
        if h is not None and s is not None:
            return sub(s, h)
    if hips is None:
        return None
    if shoulders is not None:
        v = sub(shoulders, hips)
        axis = lateral(pts)
        if axis is None:
            return None
        d = v[0] * axis[0] + v[1] * axis[1] + v[2] * axis[2]
        return (v[0] - d * axis[0], v[1] - d * axis[1], v[2] - d * axis[2])
    head = centre(pts, HEAD)
    return None if head is None else sub(head, hips)


def torso_angle(pts: list[Point | None]) -> float:
    """The torso's angle to vertical; without a torso vector, the main axis of the known
    joints (when they have one); NaN when it cannot be told."""
    deg = angle_to_vertical(torso_vector(pts))
    if math.isfinite(deg):
        return deg
    seen = [p for p in pts if p is not None]
    if len(seen) < 4:
        return math.nan
    P = np.array(seen)
    _, sv, vt = np.linalg.svd(P - P.mean(0), full_matrices=False)
    if sv[0] < 0.3 * math.sqrt(len(P)) or sv[0] < 1.5 * sv[1]:  # too small or no clear axis
        return math.nan
    return angle_to_vertical(tuple(vt[0]))


def thigh_angle(pts: list[Point | None]) -> float:
    """The thighs' (hip -> knee) mean angle to vertical (NaN: no thigh known)."""
    degs = [
        angle_to_vertical(sub(k, h))
        for hip, knee, _ in LEGS
        if (h := pts[hip]) is not None and (k := pts[knee]) is not None
    ]
    degs = [d for d in degs if math.isfinite(d)]
    return sum(degs) / len(degs) if degs else math.nan


def knee_angle(pts: list[Point | None]) -> float:
    """The more bent knee's angle between thigh and shin (180: straight; NaN: no leg with hip,
    knee and ankle known)."""
    best = math.nan
    for hip, knee, ankle in LEGS:
        h, k, f = pts[hip], pts[knee], pts[ankle]
        if h is None or k is None or f is None:
            continue
        a, b = sub(h, k), sub(f, k)
        na, nb = math.hypot(*a), math.hypot(*b)
        if na < 1e-6 or nb < 1e-6:
            continue
        c = (a[0] * b[0] + a[1] * b[1] + a[2] * b[2]) / (na * nb)
        deg = math.degrees(math.acos(max(-1.0, min(1.0, c))))
        best = deg if math.isnan(best) else min(best, deg)
    return best
