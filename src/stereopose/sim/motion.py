"""Motion of simulated workers: walking between waypoints, stopping, reaching up, bending,
entering and leaving the room.

World frame: metres, z up, floor at z = 0. A worker is summarised per frame by a few signals
(floor position, heading, gait amplitude and phase, reach and bend amounts), from which `pose`
builds the 17 COCO joints with adult proportions scaled from the body height.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from stereopose.skeleton import (
    LEFT_ANKLE,
    LEFT_EAR,
    LEFT_ELBOW,
    LEFT_EYE,
    LEFT_HIP,
    LEFT_KNEE,
    LEFT_SHOULDER,
    LEFT_WRIST,
    NOSE,
    NUM_JOINTS,
    RIGHT_ANKLE,
    RIGHT_EAR,
    RIGHT_ELBOW,
    RIGHT_EYE,
    RIGHT_HIP,
    RIGHT_KNEE,
    RIGHT_SHOULDER,
    RIGHT_WRIST,
)

# (left, right) joints of each side-to-side pair the body is built from
_HIPS, _KNEES, _ANKLES = (LEFT_HIP, RIGHT_HIP), (LEFT_KNEE, RIGHT_KNEE), (LEFT_ANKLE, RIGHT_ANKLE)
_SHOULDERS, _ELBOWS = (LEFT_SHOULDER, RIGHT_SHOULDER), (LEFT_ELBOW, RIGHT_ELBOW)
_WRISTS = (LEFT_WRIST, RIGHT_WRIST)

# Lengths as fractions of body height (adult anthropometry, Drillis & Contini).
ANKLE_Z = 0.045
SHIN = 0.24
THIGH = 0.24
TORSO = 0.293  # hip centre to shoulder centre
NECK = 0.04
HEAD = 0.06  # neck top to head centre
SHOULDER_W = 0.26
HIP_W = 0.19
UPPER_ARM = 0.186
FOREARM = 0.146

HIP_SWING = 0.35  # rad, thigh swing amplitude while walking
KNEE_SWING = 1.0  # rad, peak knee flexion in swing
ARM_SWING = 0.35  # rad
ARM_UP = 2.9  # rad from hanging: wrist above the head
BEND_HIP_BACK = 0.12  # hips move back (x height x sin bend) to keep balance
BEND_HIP_DOWN = 0.04

Door = tuple[np.ndarray, np.ndarray]  # (point on the wall (2,), inward unit normal (2,))

_UP = np.array([0.0, 0.0, 1.0])


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _two_link_knee(
    hip: np.ndarray, ankle: np.ndarray, l1: np.ndarray, l2: np.ndarray, forward: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Knee (T, 3) of a leg from hip to ankle, bending forward; ankle moved in if out of reach."""
    d = ankle - hip
    dist = np.linalg.norm(d, axis=-1)
    u = d / np.maximum(dist, 1e-9)[:, None]
    dist = np.clip(dist, 1e-6, (l1 + l2) * (1.0 - 1e-9))
    a = (l1**2 - l2**2 + dist**2) / (2.0 * dist)
    b = np.sqrt(np.maximum(l1**2 - a**2, 0.0))
    n = forward - np.sum(forward * u, axis=-1, keepdims=True) * u
    n = n / np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-9)
    knee = hip + a[:, None] * u + b[:, None] * n
    return knee, hip + dist[:, None] * u


def pose(
    height: float | np.ndarray,
    xy: np.ndarray,
    heading: np.ndarray,
    gait: np.ndarray | None = None,
    phase: np.ndarray | None = None,
    reach_left: np.ndarray | None = None,
    reach_right: np.ndarray | None = None,
    bend: np.ndarray | None = None,
) -> np.ndarray:
    """COCO-17 joints (T, 17, 3) in metres.

    height: body height(s) in metres, scalar or (T,); xy: (T, 2) floor position of the hip centre;
    heading: (T,) rad, direction faced, from the world x axis; gait: (T,) walking amplitude in
    [0, 1]; phase: (T,) gait cycle phase (rad, left leg); reach_left/right: (T,) in [0, 1], 1 =
    wrist raised above the head; bend: (T,) forward torso tilt in rad. Omitted signals are 0
    (standing still).
    """
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    T = xy.shape[0]
    zero = np.zeros(T)
    heading = np.broadcast_to(np.asarray(heading, dtype=np.float64), (T,))
    g = zero if gait is None else np.asarray(gait, dtype=np.float64)
    ph = zero if phase is None else np.asarray(phase, dtype=np.float64)
    wl = zero if reach_left is None else np.asarray(reach_left, dtype=np.float64)
    wr = zero if reach_right is None else np.asarray(reach_right, dtype=np.float64)
    beta = zero if bend is None else np.asarray(bend, dtype=np.float64)
    h1 = np.broadcast_to(np.asarray(height, dtype=np.float64), (T,))
    h = h1[:, None]

    f = np.column_stack([np.cos(heading), np.sin(heading), zero])
    left = np.column_stack([-np.sin(heading), np.cos(heading), zero])
    out = np.empty((T, NUM_JOINTS, 3))
    shoulder_c, spine = _legs_and_trunk(out, xy, h, f, left, g, ph, beta)
    _head(out, shoulder_c, spine, h, f, left, beta)
    _arms(out, _Body(h, f, left, g, ph, beta), wl, wr)
    return out


def _legs_and_trunk(
    out: np.ndarray,
    xy: np.ndarray,
    h: np.ndarray,
    f: np.ndarray,
    left: np.ndarray,
    g: np.ndarray,
    ph: np.ndarray,
    beta: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Hips, knees, ankles and shoulders into out (T, 17, 3); returns the shoulder centre and
    the spine direction (T, 3) each."""
    h1 = h[:, 0]
    # Legs by forward kinematics from the hip joints, then the stance foot is put on the floor.
    ankles_rel = []
    for phase_leg in (ph, ph + np.pi):
        th = HIP_SWING * g * np.sin(phase_leg)
        kn = g * (0.1 + (KNEE_SWING - 0.1) * np.maximum(np.cos(phase_leg), 0.0))
        thigh = -np.cos(th)[:, None] * _UP + np.sin(th)[:, None] * f
        shin = -np.cos(th - kn)[:, None] * _UP + np.sin(th - kn)[:, None] * f
        ankles_rel.append(h * (THIGH * thigh + SHIN * shin))
    # the lower ankle carries the body; a soft minimum hands the weight from one foot to the
    # other over a few frames (the body's height has no kink at each step)
    za, zb = ankles_rel[0][:, 2], ankles_rel[1][:, 2]
    k = 0.01 * h1
    d = np.abs(za - zb) / k
    # exact where the feet are level or far apart (standing, single support)
    soft_min = np.minimum(za, zb) - k * (np.log1p(np.exp(-d)) - np.log(2.0) * np.exp(-d * d))
    hip_z = ANKLE_Z * h1 - soft_min
    pelvis = np.column_stack([xy, hip_z])
    half_hip = 0.5 * HIP_W * h * left
    ankles = (pelvis + half_hip + ankles_rel[0], pelvis - half_hip + ankles_rel[1])

    # Bending moves the hips back and down; the knees follow by two-link inverse kinematics.
    sb = np.sin(beta)[:, None]
    pelvis = pelvis - BEND_HIP_BACK * h * sb * f - BEND_HIP_DOWN * h * sb * _UP
    for side, sign in enumerate((1.0, -1.0)):
        hip = pelvis + sign * half_hip
        knee, ankle = _two_link_knee(hip, ankles[side], THIGH * h1, SHIN * h1, f)
        out[:, _HIPS[side]], out[:, _KNEES[side]], out[:, _ANKLES[side]] = hip, knee, ankle

    spine = np.cos(beta)[:, None] * _UP + sb * f
    shoulder_c = pelvis + TORSO * h * spine
    half_sh = 0.5 * SHOULDER_W * h * left
    out[:, LEFT_SHOULDER], out[:, RIGHT_SHOULDER] = shoulder_c + half_sh, shoulder_c - half_sh
    return shoulder_c, spine


def _head(
    out: np.ndarray,
    shoulder_c: np.ndarray,
    spine: np.ndarray,
    h: np.ndarray,
    f: np.ndarray,
    left: np.ndarray,
    beta: np.ndarray,
) -> None:
    """Nose, eyes and ears into out (T, 17, 3). The head tilts less than the torso, to keep
    looking ahead."""
    bh = 0.6 * beta
    head_up = np.cos(bh)[:, None] * _UP + np.sin(bh)[:, None] * f
    head_fw = np.cos(bh)[:, None] * f - np.sin(bh)[:, None] * _UP
    hc = shoulder_c + NECK * h * spine + HEAD * h * head_up
    out[:, NOSE] = hc + h * (0.05 * head_fw - 0.01 * head_up)
    eye = hc + h * (0.042 * head_fw + 0.012 * head_up)
    ear = hc + h * (-0.005 * head_fw + 0.005 * head_up)
    out[:, LEFT_EYE], out[:, RIGHT_EYE] = eye + 0.017 * h * left, eye - 0.017 * h * left
    out[:, LEFT_EAR], out[:, RIGHT_EAR] = ear + 0.042 * h * left, ear - 0.042 * h * left


@dataclass(frozen=True)
class _Body:
    """Per frame: h (T, 1) height, f and left (T, 3) the forward and left directions, g the
    gait amplitude, ph its phase, beta the torso's bend (T,)."""

    h: np.ndarray
    f: np.ndarray
    left: np.ndarray
    g: np.ndarray
    ph: np.ndarray
    beta: np.ndarray


def _arms(out: np.ndarray, body: _Body, wl: np.ndarray, wr: np.ndarray) -> None:
    """Elbows and wrists into out (T, 17, 3), from the shoulders there. Arms swing against the
    legs; reaching (wl, wr: left and right, 0 to 1) raises the arm forward and up above the
    head."""
    h, f, left, g, ph, beta = body.h, body.f, body.left, body.g, body.ph, body.beta
    for k, (side, phase_arm, w) in enumerate(((1.0, ph + np.pi, wl), (-1.0, ph, wr))):
        swing = ARM_SWING * g * np.sin(phase_arm)
        phi = (1.0 - w) * (swing + 0.3 * beta) + w * ARM_UP
        elbow_flex = (1.0 - w) * (0.3 + 0.2 * g) + w * 0.15
        abd = (side * (0.12 + 0.15 * w))[:, None] * left
        upper = _unit(-np.cos(phi)[:, None] * _UP + np.sin(phi)[:, None] * f + abd)
        phi2 = phi + elbow_flex
        fore = _unit(-np.cos(phi2)[:, None] * _UP + np.sin(phi2)[:, None] * f + abd)
        out[:, _ELBOWS[k]] = out[:, _SHOULDERS[k]] + UPPER_ARM * h * upper
        out[:, _WRISTS[k]] = out[:, _ELBOWS[k]] + FOREARM * h * fore


@dataclass(frozen=True)
class Segment:
    """One piece of a worker's plan, from t0 to t1 seconds; `walk` goes from start to end."""

    kind: str  # "walk" | "idle" | "reach" | "bend"
    t0: float
    t1: float
    start: tuple[float, float]
    end: tuple[float, float]
    heading: float
    reach: tuple[float, float] = (0.0, 0.0)
    bend: float = 0.0


def _smooth(x: np.ndarray, width: int) -> np.ndarray:
    """Moving average over `width` samples (made odd), edges held."""
    k = max(1, width) | 1
    if k == 1 or x.shape[0] == 0:
        return x
    padded = np.pad(x, k // 2, mode="edge")
    return np.convolve(padded, np.full(k, 1.0 / k), mode="valid")


@dataclass(frozen=True)
class Worker:
    """A worker's body and plan; `track` gives the joints per frame.

    room: (width, depth) of the floor in metres; the worker is present while its hip centre is
    over the floor [0, width] x [0, depth].
    """

    height: float
    speed: float  # m/s while walking
    step_hz: float  # steps per second (two steps per gait cycle)
    phase0: float
    segments: tuple[Segment, ...]
    room: tuple[float, float]

    @classmethod
    def random(
        cls,
        rng: np.random.Generator,
        room: tuple[float, float],
        duration_s: float,
        *,
        enters: bool = False,
        leaves: bool = False,
        doors: tuple[Door, ...] = (),
    ) -> Worker:
        """A random worker over `duration_s` seconds; `enters`/`leaves` use one of `doors`."""
        W, D = float(room[0]), float(room[1])
        speed = float(rng.uniform(1.2, 1.5))
        segs: list[Segment] = []

        def interior(margin: float = 0.8) -> np.ndarray:
            return rng.uniform([margin, margin], [W - margin, D - margin])

        def walk(p: np.ndarray, q: np.ndarray, t: float) -> float:
            d = q - p
            dur = max(float(np.hypot(*d)) / speed, 1e-3)
            seg = Segment("walk", t, t + dur, tuple(p), tuple(q), float(np.arctan2(d[1], d[0])))
            segs.append(seg)
            return t + dur

        if enters and doors:
            door, normal = doors[int(rng.integers(len(doors)))]
            tangent = np.array([-normal[1], normal[0]])
            pos = door - 0.8 * normal + rng.uniform(-0.3, 0.3) * tangent
            heading = float(np.arctan2(normal[1], normal[0]))
            t = float(rng.uniform(0.0, 0.35)) * duration_s
            segs.append(Segment("idle", -1.0, t, tuple(pos), tuple(pos), heading))
            target = door + rng.uniform(1.0, 2.0) * normal + rng.uniform(-0.5, 0.5) * tangent
            t = walk(pos, target, t)
            pos, heading, walked = target, segs[-1].heading, True
        else:
            pos, heading = interior(), float(rng.uniform(-np.pi, np.pi))
            t, walked = -float(rng.uniform(0.0, 2.0)), bool(rng.random() < 0.5)

        while t < duration_s:
            if not walked and rng.random() < 0.75:
                target = interior()
                for _ in range(10):
                    if np.hypot(*(target - pos)) >= 1.5:
                        break
                    target = interior()
                t = walk(pos, target, t)
                pos, heading, walked = target, segs[-1].heading, True
                continue
            kind = ("idle", "reach", "bend")[int(rng.choice(3, p=[0.4, 0.35, 0.25]))]
            dur = float(rng.uniform(1.0, 3.0) if kind == "idle" else rng.uniform(1.5, 4.0))
            reach, bend = (0.0, 0.0), 0.0
            if kind == "reach":
                reach = ((1.0, 0.0), (0.0, 1.0), (1.0, 1.0))[int(rng.integers(3))]
            elif kind == "bend":
                bend = float(rng.uniform(0.5, np.deg2rad(60.0)))
            p = tuple(pos)
            segs.append(Segment(kind, t, t + dur, p, p, heading, reach, bend))
            t, walked = t + dur, False

        if leaves and doors:
            door, normal = doors[int(rng.integers(len(doors)))]
            inside, outside = door + 0.8 * normal, door - 1.0 * normal
            for k in range(len(segs) - 1, -1, -1):
                end = np.array(segs[k].end)
                on_floor = 0.0 < end[0] < W and 0.0 < end[1] < D
                need = (np.hypot(*(inside - end)) + np.hypot(*(outside - inside))) / speed
                if on_floor and segs[k].t1 + need + 0.5 <= duration_s:
                    del segs[k + 1 :]
                    t = walk(inside, outside, walk(end, inside, segs[k].t1))
                    o = tuple(outside)
                    segs.append(Segment("idle", t, duration_s + 1.0, o, o, segs[-1].heading))
                    break
        return cls(
            height=float(rng.uniform(1.55, 1.95)),
            speed=speed,
            step_hz=float(rng.uniform(1.7, 1.9)),
            phase0=float(rng.uniform(0.0, 2.0 * np.pi)),
            segments=tuple(segs),
            room=(W, D),
        )

    def signals(self, num_frames: int, fps: float) -> dict[str, np.ndarray]:
        """Per-frame signals (T,) of the plan: x, y, heading, gait, phase, reach_left,
        reach_right, bend, present."""
        times = np.arange(num_frames) / fps
        xy = np.zeros((num_frames, 2))
        sig: dict[str, np.ndarray] = {
            k: np.zeros(num_frames) for k in ("heading", "gait", "reach_left", "reach_right")
        }
        bend = np.zeros(num_frames)
        for s in self.segments:
            m = (times >= s.t0) & (times < s.t1)
            if not m.any():
                continue
            if s.kind == "walk":
                frac = ((times[m] - s.t0) / (s.t1 - s.t0))[:, None]
                xy[m] = np.asarray(s.start) + frac * (np.asarray(s.end) - np.asarray(s.start))
                sig["gait"][m] = 1.0
            else:
                xy[m] = s.start
            sig["heading"][m] = s.heading
            sig["reach_left"][m], sig["reach_right"][m] = s.reach
            bend[m] = s.bend
        ramp = round(0.4 * fps)
        for k in ("gait", "reach_left", "reach_right"):
            sig[k] = _smooth(sig[k], ramp)
        sig["bend"] = _smooth(bend, ramp)
        # People turn, speed up and slow down over most of a second, not from one frame to the
        # next: two moving averages make the heading's rate and the velocity ramp smoothly.
        w = round(0.35 * fps)
        sig["heading"] = _smooth(_smooth(np.unwrap(sig["heading"]), w), w)
        xy = np.column_stack([_smooth(_smooth(xy[:, k], w), w) for k in range(2)])
        sig["phase"] = self.phase0 + np.cumsum(np.pi * self.step_hz * sig["gait"] / fps)
        W, D = self.room
        sig["present"] = (xy[:, 0] >= 0) & (xy[:, 0] <= W) & (xy[:, 1] >= 0) & (xy[:, 1] <= D)
        sig["x"], sig["y"] = xy[:, 0], xy[:, 1]
        return sig

    def track(
        self, num_frames: int, fps: float, xy: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Joints (T, 17, 3) in metres, NaN where absent, and presence (T,) bool.

        xy: (T, 2) floor positions of the hip centre to use instead of the plan's (the plan's
        moved aside by keep_apart); presence stays the plan's.
        """
        s = self.signals(num_frames, fps)
        joints = pose(
            self.height,
            np.column_stack([s["x"], s["y"]]) if xy is None else xy,
            s["heading"],
            s["gait"],
            s["phase"],
            s["reach_left"],
            s["reach_right"],
            s["bend"],
        )
        joints[~s["present"]] = np.nan
        return joints, s["present"]


def keep_apart(
    xy: np.ndarray,
    present: np.ndarray,
    min_m: float,
    fps: float,
    room: tuple[float, float],
    iterations: int = 40,
) -> np.ndarray:
    """Floor positions (N, T, 2) of N workers' hip centres moved so that no two present
    workers come closer than min_m: two bodies cannot overlap, and people passing or working
    side by side give way.

    Each pair too close is pushed apart along the line between them, each by half the
    shortfall; the pushes are smoothed over time as the plans' own positions are (people step
    aside over most of a second, not from one frame to the next), and repeated until every
    pair is far enough apart. present: (N, T) bool; positions of a present worker stay on
    the floor [0, width] x [0, depth] of `room`.
    """
    out = np.array(xy, dtype=np.float64)
    N, T = present.shape
    if N < 2 or T == 0:
        return out
    w = round(0.35 * fps)
    both = present[:, None] & present[None] & ~np.eye(N, dtype=bool)[:, :, None]  # (N, N, T)
    # a fixed direction for two workers at the very same spot: along x, by index
    tie = np.sign(np.arange(N)[:, None] - np.arange(N)[None])[..., None]  # (N, N, 1)
    lo, hi = np.array([0.05, 0.05]), np.array(room, dtype=np.float64) - 0.05
    for _ in range(iterations):
        d = out[:, None] - out[None]  # (N, N, T, 2), from m to n
        dist = np.hypot(d[..., 0], d[..., 1])
        short = both & (dist < min_m)
        if not short.any():
            break
        with np.errstate(invalid="ignore", divide="ignore"):
            unit = np.where(dist[..., None] > 1e-9, d / dist[..., None], 0.0)
        unit[..., 0] = np.where(dist > 1e-9, unit[..., 0], tie)
        # a little more than half the shortfall each, so the smoothing does not leave a gap
        step = np.where(short, 0.6 * (min_m - dist), 0.0)[..., None] * unit
        push = step.sum(axis=1)  # (N, T, 2)
        for k in range(2):
            push[..., k] = np.stack([_smooth(_smooth(p, w), w) for p in push[..., k]])
        out += push
        out = np.where(present[..., None], np.clip(out, lo, hi), out)
    return out
