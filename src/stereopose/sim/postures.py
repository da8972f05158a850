"""Simulated workers who kneel, squat, sit, fall and get up, and their scripts.

A body shape is a few numbers on top of motion.pose's standing, walking, bending and reaching
body: how far the pelvis drops and moves back, where each foot goes (the knees follow by
two-link inverse kinematics, so every bone keeps its length), and how far the whole body tilts
from vertical about the floor point under the hips, toward a direction. A lying body is the
standing one tilted a right angle and then lifted so that no joint sinks into the floor: the
joints lie inside the body, a few centimetres above the surface it rests on.

An Actor follows a script of Acts, one after the other; each act eases from the previous shape
into its own over its first `ease_s` seconds. A fall tilts the body to the floor with growing
speed in 0.5-0.9 s while the knees buckle (the hips drop about 0.8 m in under a second); a
get-up rises through a crouch in seconds.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from stereopose.sim.motion import SHIN, THIGH, _smooth, _two_link_knee, pose
from stereopose.skeleton import (
    LEFT_ANKLE,
    LEFT_HIP,
    LEFT_KNEE,
    LEFT_SHOULDER,
    NUM_JOINTS,
    RIGHT_ANKLE,
    RIGHT_HIP,
    RIGHT_KNEE,
    RIGHT_SHOULDER,
)

# Shape vector: pelvis drop and back shift, left and right foot (forward, up) offsets (all as
# fractions of the body height), forward bend (rad), tilt from vertical (rad).
DROP, BACK, LF, LU, RF, RU, BEND, TILT = range(8)
SHAPE_SIZE = 8


def _shape(**kw: float) -> np.ndarray:
    names = ("drop", "back", "lf", "lu", "rf", "ru", "bend", "tilt")
    v = np.zeros(SHAPE_SIZE)
    for k, x in kw.items():
        v[names.index(k)] = x
    return v


# Standing hips are 0.525 body heights up (ankle 0.045 + thigh 0.24 + shin 0.24).
SHAPES: dict[str, np.ndarray] = {
    "stand": _shape(),
    # deep squat, heels down: hips at 0.28 heights, back over the heels, torso leaning
    "squat": _shape(drop=0.245, back=0.09, bend=0.45),
    # on the left knee (thigh vertical, shin on the floor), right foot forward
    "kneel": _shape(drop=0.255, lf=-0.235, lu=0.015, rf=0.22, bend=0.15),
    # on both knees
    "kneel2": _shape(drop=0.255, lf=-0.235, lu=0.015, rf=-0.235, ru=0.015, bend=0.2),
    # on a box or step about 0.5 m high: thighs level, shins vertical
    "sit": _shape(drop=0.24, back=0.22, lf=0.02, rf=0.02, bend=0.1),
    # on the floor, legs forward, torso upright
    "sit_floor": _shape(drop=0.455, back=0.12, lf=0.3, rf=0.3, bend=0.05),
    # bending into a panel; stooping to the floor with straight legs
    "bend": _shape(bend=1.0),
    "stoop": _shape(bend=1.35),
    "lie": _shape(tilt=np.pi / 2),
}

# How far above the floor each joint stays at least (metres; ankles: 0.045 body heights): the
# joint centres lie inside the body, this far from the skin that touches the floor.
_CLEARANCE_M = np.array(
    [
        0.09,
        0.09,
        0.09,
        0.09,
        0.09,
        0.07,
        0.07,
        0.04,
        0.04,
        0.03,
        0.03,
        0.09,
        0.09,
        0.05,
        0.05,
        0.0,
        0.0,
    ]
)
_LEGS = (LEFT_KNEE, RIGHT_KNEE, LEFT_ANKLE, RIGHT_ANKLE)
_UPPER = np.array([j for j in range(NUM_JOINTS) if j not in _LEGS])
_UP = np.array([0.0, 0.0, 1.0])


def body(height: float, xy: np.ndarray, signals: Mapping[str, np.ndarray]) -> np.ndarray:
    """COCO-17 joints (T, 17, 3) in metres of a body of `height` metres.

    xy: (T, 2) floor point under the standing hip centre, also the point the body tilts about;
    signals: "shape" (T, 8) the shapes; "heading" (T,) rad from world x; "fall_dir" (T,) world
    azimuth (rad) toward which the head goes when tilting; "gait", "phase", "reach_left",
    "reach_right" as for motion.pose, each optional (the bend is the shape's).
    """
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    shape = np.asarray(signals["shape"], dtype=np.float64)
    heading, fall_dir = signals["heading"], signals["fall_dir"]
    gait, phase = signals.get("gait"), signals.get("phase")
    reach_left, reach_right = signals.get("reach_left"), signals.get("reach_right")
    T = xy.shape[0]
    if shape.shape != (T, SHAPE_SIZE):
        raise ValueError(f"shape must be ({T}, {SHAPE_SIZE}), got {shape.shape}")
    h = float(height)
    heading = np.broadcast_to(np.asarray(heading, dtype=np.float64), (T,))
    J = pose(h, xy, heading, gait, phase, reach_left, reach_right, shape[:, BEND])
    f = np.column_stack([np.cos(heading), np.sin(heading), np.zeros(T)])

    # pelvis down and back: the upper body moves with it, the feet go where the shape says
    shift = -h * (shape[:, BACK, None] * f + shape[:, DROP, None] * _UP)
    J[:, _UPPER] += shift[:, None]
    for hip, knee, ankle, fw, upw in (
        (LEFT_HIP, LEFT_KNEE, LEFT_ANKLE, LF, LU),
        (RIGHT_HIP, RIGHT_KNEE, RIGHT_ANKLE, RF, RU),
    ):
        foot = J[:, ankle] + h * (shape[:, fw, None] * f + shape[:, upw, None] * _UP)
        J[:, knee], J[:, ankle] = _two_link_knee(
            J[:, hip], foot, np.full(T, THIGH * h), np.full(T, SHIN * h), f
        )

    # tilt about the floor point under the hips, toward fall_dir (Rodrigues, axis up x dir)
    tilt = shape[:, TILT]
    if np.any(tilt != 0.0):
        d = np.column_stack([np.cos(fall_dir), np.sin(fall_dir), np.zeros(T)])
        axis = np.cross(_UP, d)
        pivot = np.column_stack([xy, np.zeros(T)])[:, None]
        v = J - pivot
        c, s = np.cos(tilt)[:, None, None], np.sin(tilt)[:, None, None]
        a = axis[:, None]
        v = v * c + np.cross(a, v) * s + a * np.sum(a * v, -1, keepdims=True) * (1.0 - c)
        J = pivot + v
    # nothing sinks into the floor
    clearance = _CLEARANCE_M.copy()
    clearance[[LEFT_ANKLE, RIGHT_ANKLE]] = 0.045 * h
    lift = np.maximum(0.0, np.max(clearance - J[..., 2], axis=1))
    J[..., 2] += lift[:, None]
    return J


@dataclass(frozen=True)
class Act:
    """One step of a script, from t0 to t1 seconds.

    kind: "walk" (start -> end, standing shape) or a shape of SHAPES ("stand", "squat", "kneel",
    "kneel2", "sit", "sit_floor", "lie"); `fall` and `get_up` are ways into "lie" and out of it
    (to "stand"). ease_s: time to go from the previous shape into this one. reach: (left,
    right) arm raise in [0, 1] (1: wrist above the head, about 0.55: forward at shoulder
    height). work: the hands move (tool work) with this amplitude of reach. fall_dir: world
    azimuth of a fall (rad).
    """

    kind: str
    t0: float
    t1: float
    start: tuple[float, float]
    end: tuple[float, float]
    heading: float
    ease_s: float = 1.0
    reach: tuple[float, float] = (0.0, 0.0)
    work: float = 0.0
    fall_dir: float = 0.0

    def shape_name(self) -> str:
        if self.kind in ("walk", "get_up"):
            return "stand"
        return "lie" if self.kind == "fall" else self.kind


KINDS = ("walk", "fall", "get_up", *SHAPES)


@dataclass(frozen=True)
class Fall:
    """A scripted fall: the body starts going down at t0, is on the floor at t_floor, and starts
    getting up at t_up (None: stays down to the end)."""

    worker: int
    t0: float
    t_floor: float
    t_up: float | None

    def down_for(self, end_s: float) -> float:
        """Seconds on the floor before getting up (or before end_s)."""
        return (end_s if self.t_up is None else self.t_up) - self.t_floor


@dataclass(frozen=True)
class Actor:
    """A worker's body and script; `track` gives the joints per frame.

    room: (width, depth) of the floor; the worker is present while its standing hip point is
    over it.
    """

    height: float
    step_hz: float
    phase0: float
    acts: tuple[Act, ...]
    room: tuple[float, float]
    seed: int = 0
    falls: tuple[Fall, ...] = field(default=())

    def __post_init__(self) -> None:
        for a in self.acts:
            if a.kind not in KINDS:
                raise ValueError(f"unknown act {a.kind!r}; expected one of {KINDS}")

    def signals(self, num_frames: int, fps: float) -> dict[str, np.ndarray]:
        """Per-frame signals: x, y, heading, gait, phase, reach_left, reach_right (T,), shape
        (T, 8), fall_dir (T,), present (T,) bool."""
        T = num_frames
        times = np.arange(T) / fps
        xy = np.full((T, 2), np.nan)
        heading, gait = np.zeros(T), np.zeros(T)
        reach = np.zeros((T, 2))
        shape = np.zeros((T, SHAPE_SIZE))
        fall_dir = np.zeros(T)
        rng = np.random.default_rng(self.seed)
        prev_shape, prev_reach = SHAPES["stand"], np.zeros(2)
        for a in self.acts:
            target = SHAPES[a.shape_name()]
            m = (times >= a.t0) & (times < a.t1)
            t = times[m]
            s = np.clip((t - a.t0) / max(a.ease_s, 1e-6), 0.0, 1.0)
            bump = np.sin(np.pi * s)
            if a.kind == "fall":
                # toppling: the tilt grows with the square of time; knees buckle, arms fly out
                e = s * s
                sh = prev_shape + e[:, None] * (target - prev_shape)
                sh[:, DROP] += 0.12 * bump
                sh[:, BEND] += 0.35 * bump
                r = prev_reach + s[:, None] * (np.asarray(a.reach) - prev_reach)
                r += 0.4 * bump[:, None]
            else:
                e = s * s * (3.0 - 2.0 * s)  # smoothstep
                sh = prev_shape + e[:, None] * (target - prev_shape)
                if a.kind == "get_up":  # up through a crouch, leaning forward
                    sh[:, DROP] += 0.22 * bump
                    sh[:, BEND] += 0.6 * bump
                r = prev_reach + e[:, None] * (np.asarray(a.reach) - prev_reach)
            if a.work > 0.0 and m.any():
                wobble = a.work * np.sin(
                    2 * np.pi * 0.7 * t + rng.uniform(0, 2 * np.pi, 2)[:, None]
                )
                r = r + (e[:, None] * wobble.T)
            shape[m], reach[m] = sh, np.clip(r, 0.0, 1.0)
            if a.kind == "walk":
                frac = ((t - a.t0) / (a.t1 - a.t0))[:, None]
                xy[m] = np.asarray(a.start) + frac * (np.subtract(a.end, a.start))
                gait[m] = 1.0
            else:
                xy[m] = a.start
            heading[m], fall_dir[m] = a.heading, a.fall_dir
            prev_shape, prev_reach = target, np.asarray(a.reach, dtype=np.float64)
        known = np.isfinite(xy[:, 0])
        if known.any():  # before the first act and after the last: where the script ends
            first, last = np.flatnonzero(known)[[0, -1]]
            xy[:first], xy[last + 1 :] = xy[first], xy[last]
            heading[:first], heading[last + 1 :] = heading[first], heading[last]
            shape[last + 1 :], fall_dir[last + 1 :] = shape[last], fall_dir[last]
        ramp = round(0.4 * fps)
        gait = _smooth(gait, ramp)
        w = round(0.35 * fps)
        heading = _smooth(_smooth(np.unwrap(heading), w), w)
        # walking positions ramp as motion.Worker's do; a body on the floor does not slide
        smooth_xy = np.column_stack([_smooth(_smooth(xy[:, k], w), w) for k in range(2)])
        tilted = shape[:, TILT] > 0.0
        xy = np.where(tilted[:, None], xy, smooth_xy)
        W, D = self.room
        present = (xy[:, 0] >= 0) & (xy[:, 0] <= W) & (xy[:, 1] >= 0) & (xy[:, 1] <= D)
        return {
            "x": xy[:, 0],
            "y": xy[:, 1],
            "heading": heading,
            "gait": gait,
            "phase": self.phase0 + np.cumsum(np.pi * self.step_hz * gait / fps),
            "reach_left": reach[:, 0],
            "reach_right": reach[:, 1],
            "shape": shape,
            "fall_dir": fall_dir,
            "present": present,
        }

    def track(
        self, num_frames: int, fps: float, xy: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Joints (T, 17, 3) in metres, NaN where absent, and presence (T,) bool; xy: (T, 2)
        floor points to use instead of the script's (moved aside by keep_apart)."""
        s = self.signals(num_frames, fps)
        joints = body(self.height, np.column_stack([s["x"], s["y"]]) if xy is None else xy, s)
        joints[~s["present"]] = np.nan
        return joints, s["present"]


def hips_z(joints: np.ndarray) -> np.ndarray:
    """(..., 17, 3) -> (...) height of the hip centre."""
    return 0.5 * (joints[..., LEFT_HIP, 2] + joints[..., RIGHT_HIP, 2])


def torso_tilt(joints: np.ndarray) -> np.ndarray:
    """(..., 17, 3) -> (...) angle (rad) of hip centre -> shoulder centre from vertical."""
    sh = 0.5 * (joints[..., LEFT_SHOULDER, :] + joints[..., RIGHT_SHOULDER, :])
    hp = 0.5 * (joints[..., LEFT_HIP, :] + joints[..., RIGHT_HIP, :])
    v = sh - hp
    return np.arccos(np.clip(v[..., 2] / np.linalg.norm(v, axis=-1), -1.0, 1.0))
