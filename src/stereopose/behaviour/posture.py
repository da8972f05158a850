"""Posture per person and frame, from the 3D joints and their recent motion.

World frame: metres, z up, floor at z = 0; joints are COCO-17 (stereopose.skeleton), NaN where
missing. Every posture is decided by geometry with a threshold of PostureSettings:

- torso angle: between the hip centre -> shoulder centre vector and the vertical (one side
  alone when only that side is known; a hip and a shoulder of opposite sides less their
  sideways part; without shoulders, hips -> head; without hips, the main axis of the joints
  that are known);
- hip height above the feet (the lower ankle less `ankle_m`; the floor, z = 0, when no ankle
  is known below the hips: so a person standing on a step, a ladder or a floor lower than the
  world's z = 0 is not crouching) against the person's own standing hip height (a high
  quantile of their hip heights while upright, PostureTracker; `standing_hip_m` until enough
  are seen);
- knee angle: between thigh and shin at the knee (180 degrees: straight); thigh angle: hip ->
  knee against vertical;
- speed: of the person's floor point over the last `walk_window_s`.

The postures, in the order they are tested:

- lying: the body's top (the highest of the head and shoulders; the hips when neither is known)
  less than `lying_height_m` above the floor it lies on (the lower ankle less `ankle_m`; z = 0
  when no ankle is known), with the torso at least `lying_deg` from vertical and the thighs at
  least `lying_thigh_deg` (each where it is known). Joints that are missing (a body half out
  of view, seen by two cameras) are left out.
- crouching (kneeling, squatting, sitting): hips below `low_hip_ratio` x the standing hip height
  (without hips: the shoulders lowered as much), with the legs bent where they are known (a
  knee bent below `knee_bent_deg` or the thighs `crouch_thigh_deg` from vertical).
- bending: hips high, torso at least `bend_deg` from vertical.
- walking / standing: upright, the floor point moving at least `walk_speed_m_s` or not.
- unknown: fewer than `min_joints` joints, or only limbs that tell nothing.

Flags (not for a lying body): `arms_raised`, a wrist above the top of the head (`raised_m`
above it; above the shoulders by `raised_shoulder_m` when the head is not known); `reaching`, a
wrist farther than `reach_m` on the floor plan from its shoulder (from the shoulders' or hips'
centre when that shoulder is missing).
"""

from __future__ import annotations

import bisect
import math
from collections import deque
from dataclasses import dataclass, replace

import numpy as np

from stereopose.behaviour.body import (
    HEAD,
    HIPS,
    SHOULDERS,
    WRISTS,
    Point,
    centre,
    knee_angle,
    known,
    mean_z,
    points,
    thigh_angle,
    torso_angle,
)
from stereopose.skeleton import (
    LEFT_ANKLE,
    NUM_JOINTS,
    RIGHT_ANKLE,
)
from stereopose.types import People3D
from stereopose.zones.debounce import TIME_EPS

__all__ = [
    "DEFAULT_SETTINGS",
    "FLAGS",
    "POSTURES",
    "UNKNOWN",
    "Posture",
    "PostureSettings",
    "PostureTracker",
    "classify",
]

POSTURES = ("standing", "walking", "bending", "crouching", "lying")
UNKNOWN = "unknown"
FLAGS = ("arms_raised", "reaching")
UPRIGHT = frozenset({"standing", "walking", "bending"})  # "up" again after a fall

# standing shoulder height over standing hip height (adult proportions: 0.818 / 0.525)
SHOULDER_OVER_HIP = 1.56
_BINS_M = np.arange(0.3, 1.5001, 0.01)  # standing hip height histogram: bin edges, metres
_BIN_EDGES = _BINS_M.tolist()


@dataclass(frozen=True)
class PostureSettings:
    """The thresholds of the postures (see the module). Heights in metres above the floor,
    angles in degrees, speeds in m/s, times in seconds.

    standing_hip_m: a person's standing hip height until their own is known (adults: ~0.9).
    hip_quantile: the quantile of a person's upright hip heights taken as their standing one.
    min_samples: upright frames needed before a person's own standing height is used.
    low_hip_ratio: hips below this share of the standing height: crouching.
    ankle_m: the ankle joint's height above the sole (hip heights are taken above the feet).
    min_standing_hip_m: upright frames with the hips lower than this above the feet are not
        taken as standing height samples.
    lying_height_m: the body's top (head, shoulders) below this: lying (with lying_deg).
    lying_deg: torso at least this far from vertical for lying.
    lying_thigh_deg: thighs (where known) at least this far from vertical for lying (a worker
        kneeling, thighs upright, bent forward into a low panel is not lying).
    bend_deg: torso at least this far from vertical, hips high: bending.
    upright_deg: torso within this of vertical: an upright frame (standing height samples).
    knee_bent_deg, crouch_thigh_deg: the legs are bent when a knee's angle is below
        knee_bent_deg or the thighs are crouch_thigh_deg or more from vertical (crouching needs
        them bent where they are known; upright frames with them bent are no standing samples).
    walk_speed_m_s, walk_window_s: walking when the floor point moves this fast over the window.
    drop_dt_s, drop_window_s: the hips' drop speed is the peak, over the last drop_window_s, of
        their downward speed measured over drop_dt_s.
    raised_m: a wrist this far above the head's top is raised; raised_shoulder_m: above the
        shoulders, when no head joint is known.
    reach_m: a wrist this far (floor plan) from its shoulder is reaching.
    min_joints: fewer known joints: unknown.
    """

    standing_hip_m: float = 0.9
    hip_quantile: float = 0.9
    min_samples: int = 12
    low_hip_ratio: float = 0.72
    ankle_m: float = 0.07
    min_standing_hip_m: float = 0.6
    lying_height_m: float = 0.7
    lying_deg: float = 45.0
    lying_thigh_deg: float = 40.0
    bend_deg: float = 30.0
    upright_deg: float = 20.0
    knee_bent_deg: float = 140.0
    crouch_thigh_deg: float = 45.0
    walk_speed_m_s: float = 0.3
    walk_window_s: float = 1.0
    drop_dt_s: float = 0.2
    drop_window_s: float = 1.0
    raised_m: float = 0.0
    raised_shoulder_m: float = 0.35
    reach_m: float = 0.45
    min_joints: int = 3


DEFAULT_SETTINGS = PostureSettings()


@dataclass(frozen=True)
class Posture:
    """One person's posture at one frame.

    posture: one of POSTURES, or "unknown"; flags: a subset of FLAGS, in that order.
    torso_deg: torso angle to vertical (NaN: unknown); hip_height_m: the hip centre's height
    above the feet (see the module; NaN: no hip known); standing_hip_m: the standing hip
    height it was compared with; thigh_deg: the thighs' angle to vertical;
    trunk_m: the hips' height, or the shoulders' without hips (falls are measured on it);
    ground_m: the floor under the body (the lower ankle less ankle_m; 0 without ankles);
    top_m: the body's top (head, shoulders; hips without them); knee_deg: the more bent knee's
    angle (NaN: unknown); speed_m_s: floor speed (NaN: unknown); drop_m_s: the trunk's peak
    drop speed over the last drop_window_s (0 when it did not drop; NaN: unknown); wrist_m:
    the higher wrist's height; reach_m: the farther wrist's floor distance from its shoulder.
    """

    posture: str
    flags: tuple[str, ...] = ()
    torso_deg: float = math.nan
    hip_height_m: float = math.nan
    standing_hip_m: float = math.nan
    trunk_m: float = math.nan
    top_m: float = math.nan
    knee_deg: float = math.nan
    thigh_deg: float = math.nan
    ground_m: float = 0.0
    speed_m_s: float = math.nan
    drop_m_s: float = math.nan
    wrist_m: float = math.nan
    reach_m: float = math.nan

    @property
    def upright(self) -> bool:
        """Standing, walking or bending: up on their feet."""
        return self.posture in UPRIGHT


def _feet_z(pts: list[Point | None], trunk: float, s: PostureSettings) -> float:
    """Where the feet are: the lower ankle less ankle_m, or the floor (0) when no ankle is
    known at least 0.2 m below the trunk (an ankle at hip height is no foot to stand on)."""
    ankles = [p[2] for p in known(pts, (LEFT_ANKLE, RIGHT_ANKLE))]
    if not ankles:
        return 0.0
    z = min(ankles)
    if math.isfinite(trunk) and z > trunk - 0.2:
        return 0.0
    return z - s.ankle_m


def _legs_bent(knee: float, thigh: float, s: PostureSettings) -> bool:
    """A knee bent or the thighs inclined (each where known)."""
    return (math.isfinite(knee) and knee < s.knee_bent_deg) or (
        math.isfinite(thigh) and thigh >= s.crouch_thigh_deg
    )


def _flags(pts: list[Point | None], s: PostureSettings) -> tuple[tuple[str, ...], float, float]:
    """(flags, highest wrist height, farthest wrist reach)."""
    wrists = known(pts, WRISTS)
    if not wrists:
        return (), math.nan, math.nan
    wrist_m = max(w[2] for w in wrists)
    head = known(pts, HEAD)
    if head:
        raised = wrist_m > max(p[2] for p in head) + s.raised_m
    else:
        shoulders = mean_z(pts, SHOULDERS)
        raised = math.isfinite(shoulders) and wrist_m > shoulders + s.raised_shoulder_m
    reach = math.nan
    mid = centre(pts, SHOULDERS) or centre(pts, HIPS)
    for w, sh in zip(WRISTS, SHOULDERS, strict=True):
        base = pts[sh] or mid
        wrist = pts[w]
        if wrist is not None and base is not None:
            d = math.hypot(wrist[0] - base[0], wrist[1] - base[1])
            reach = d if math.isnan(reach) else max(reach, d)
    flags = []
    if raised:
        flags.append("arms_raised")
    if math.isfinite(reach) and reach > s.reach_m:
        flags.append("reaching")
    return tuple(flags), wrist_m, reach


def classify(
    joints: np.ndarray,
    standing_hip_m: float | None = None,
    speed_m_s: float = math.nan,
    settings: PostureSettings = PostureSettings(),  # frozen: never changed
    drop_m_s: float = math.nan,
) -> Posture:
    """The posture of one skeleton: joints (17, 3) metres, world frame z up, NaN = missing.

    standing_hip_m: the person's standing hip height (None: settings.standing_hip_m);
    speed_m_s: their floor speed (NaN: unknown, taken as standing still); drop_m_s: passed
    through into the result (PostureTracker measures it)."""
    return _classify(points(joints), standing_hip_m, speed_m_s, settings, drop_m_s)


def _classify(
    pts: list[Point | None],
    standing_hip_m: float | None,
    speed_m_s: float,
    settings: PostureSettings,
    drop_m_s: float,
) -> Posture:
    s = settings
    ref = s.standing_hip_m if standing_hip_m is None else float(standing_hip_m)
    n_known = sum(p is not None for p in pts)
    hip_z = mean_z(pts, HIPS)
    shoulders = mean_z(pts, SHOULDERS)
    trunk = hip_z if math.isfinite(hip_z) else shoulders
    feet = _feet_z(pts, trunk, s)
    hip = hip_z - feet
    seen = Posture(
        UNKNOWN,
        hip_height_m=hip,
        standing_hip_m=ref,
        trunk_m=trunk,
        speed_m_s=speed_m_s,
        drop_m_s=drop_m_s,
    )  # what is measured, the posture told below
    if n_known < s.min_joints:
        return seen
    torso = torso_angle(pts)
    knee = knee_angle(pts)
    upper = known(pts, HEAD + SHOULDERS) or known(pts, HIPS)
    top = max(p[2] for p in upper) if upper else math.nan
    seen = replace(seen, torso_deg=torso, top_m=top, knee_deg=knee)
    if math.isnan(top):  # only limbs: a long low body lying, or nothing to tell
        highest = max(p[2] for p in pts if p is not None)
        if math.isfinite(torso) and torso >= s.lying_deg and highest < s.lying_height_m:
            return replace(seen, posture="lying")
        return seen
    thigh = thigh_angle(pts)
    ankles = [p[2] for p in known(pts, (LEFT_ANKLE, RIGHT_ANKLE))]
    ground = min(ankles) - s.ankle_m if ankles else 0.0  # a platform's floor, or z = 0
    seen = replace(seen, thigh_deg=thigh, ground_m=ground)
    if (
        top - ground < s.lying_height_m
        and (math.isnan(torso) or torso >= s.lying_deg)
        and (math.isnan(thigh) or thigh >= s.lying_thigh_deg)
    ):
        return replace(seen, posture="lying")
    flags, wrist_m, reach = _flags(pts, s)
    seen = replace(seen, flags=flags, wrist_m=wrist_m, reach_m=reach)
    if math.isfinite(hip):
        low = hip < s.low_hip_ratio * ref
    elif math.isfinite(shoulders):  # the shoulders as low as the hips would be
        drop = (1.0 - s.low_hip_ratio) * ref
        low = shoulders - feet < ref * SHOULDER_OVER_HIP - drop and not (
            math.isfinite(torso) and torso >= s.bend_deg
        )
    else:
        return seen
    if low and (math.isfinite(knee) or math.isfinite(thigh)):
        low = _legs_bent(knee, thigh, s)
    if low:
        return replace(seen, posture="crouching")
    if math.isfinite(torso) and torso >= s.bend_deg:
        return replace(seen, posture="bending")
    walking = math.isfinite(speed_m_s) and speed_m_s >= s.walk_speed_m_s
    return replace(seen, posture="walking" if walking else "standing")


class _Person:
    """One person's recent motion and standing height (bounded)."""

    def __init__(self, maxlen: int) -> None:
        self.floor: deque[tuple[float, float, float]] = deque(maxlen=maxlen)  # t, x, y
        self.trunk: deque[tuple[float, float]] = deque(maxlen=maxlen)  # t, trunk height
        self.drops: deque[tuple[float, float]] = deque(maxlen=maxlen)  # t, drop speed
        self.hist = np.zeros(len(_BINS_M) - 1, dtype=np.int64)
        self.samples = 0  # the histogram's total
        self._ref: tuple[int, float] | None = None  # (samples, standing hip height) cached
        self.last_t = -math.inf
        self.last: Posture | None = None

    def standing_hip(self, s: PostureSettings) -> float:
        n = self.samples
        if n < s.min_samples:
            return s.standing_hip_m
        if self._ref is None or self._ref[0] != n:  # recomputed only when a sample came
            k = int(np.searchsorted(np.cumsum(self.hist), s.hip_quantile * n))
            k = min(k, len(self.hist) - 1)
            self._ref = (n, float(0.5 * (_BINS_M[k] + _BINS_M[k + 1])))
        return self._ref[1]


class PostureTracker:
    """Per person id: recent motion and the person's own standing height (bounded history;
    forget ids whose track ended). `update` once per frame.

    fps: the frame rate (sizes the motion history); lost_s: a person unseen this long is
    forgotten (the tracker's max_lost_s). A person the tracker only predicts at a frame (not
    seen) keeps the posture last seen.
    """

    def __init__(
        self,
        fps: float,
        settings: PostureSettings = PostureSettings(),  # frozen: never changed
        lost_s: float = 3.0,
    ) -> None:
        self.fps = float(fps)
        self.settings = settings
        self.lost_s = float(lost_s)
        window = max(settings.walk_window_s, settings.drop_window_s + settings.drop_dt_s)
        self._maxlen = max(8, math.ceil(window * self.fps * 1.5) + 2)
        self.people: dict[int, _Person] = {}

    def update(self, t: float, people: People3D) -> dict[int, Posture]:
        """The posture of each person of this frame, by id."""
        out: dict[int, Posture] = {}
        predicted = people.predicted
        for p in range(len(people)):
            pid = int(people.ids[p])
            person = self.people.get(pid)
            if person is None:
                person = self.people[pid] = _Person(self._maxlen)
            if predicted is not None and predicted[p] and person.last is not None:
                out[pid] = person.last
                continue
            out[pid] = person.last = self._step(person, t, people.joints[p])
            person.last_t = t
        self._forget(t)
        return out

    def _step(self, person: _Person, t: float, J: np.ndarray) -> Posture:
        s = self.settings
        pts = points(J)
        floor = centre(pts, HIPS) or centre(pts, tuple(range(NUM_JOINTS)))
        speed = math.nan
        if floor is not None:
            x, y = floor[0], floor[1]
            person.floor.append((t, x, y))
            speed = self._speed(person.floor, t, x, y)
        trunk = mean_z(pts, HIPS)
        if math.isnan(trunk):
            trunk = mean_z(pts, SHOULDERS)
        drop = self._drop(person, t, trunk)
        ref = person.standing_hip(s)
        posture = _classify(pts, ref, speed, s, drop)
        hip = posture.hip_height_m
        if (
            math.isfinite(hip)
            and hip >= s.min_standing_hip_m
            and math.isfinite(posture.torso_deg)
            and posture.torso_deg <= s.upright_deg
            and not _legs_bent(posture.knee_deg, posture.thigh_deg, s)
            and (posture.posture != "crouching" or math.isfinite(posture.knee_deg))
        ):
            k = bisect.bisect_left(_BIN_EDGES, hip) - 1
            if 0 <= k < len(person.hist):
                person.hist[k] += 1
                person.samples += 1
                if person.samples > 100_000:  # keeps adapting; the counts stay bounded
                    person.hist //= 2
                    person.samples = int(person.hist.sum())
        return posture

    def _speed(self, floor: deque, t: float, x: float, y: float) -> float:
        w = self.settings.walk_window_s
        while len(floor) > 1 and t - floor[0][0] > w + TIME_EPS:
            floor.popleft()
        t0, x0, y0 = floor[0]
        if t - t0 < 0.5 * w:  # too short a history to tell
            return math.nan
        return math.hypot(x - x0, y - y0) / (t - t0)

    def _drop(self, person: _Person, t: float, z: float) -> float:
        s = self.settings
        hist, drops = person.trunk, person.drops
        if math.isfinite(z):
            hist.append((t, z))
            while len(hist) > 1 and t - hist[0][0] > s.drop_dt_s + s.drop_window_s:
                hist.popleft()
            # the sample about drop_dt_s back (the latest at least that old)
            back = None
            for tb, zb in hist:
                if t - tb >= s.drop_dt_s - TIME_EPS:
                    back = (tb, zb)
                else:
                    break
            if back is not None:
                drops.append((t, (back[1] - z) / (t - back[0])))
        while drops and t - drops[0][0] > s.drop_window_s + TIME_EPS:
            drops.popleft()
        if not drops:
            return math.nan
        return max(0.0, max(v for _, v in drops))

    def _forget(self, t: float) -> None:
        gone = [pid for pid, p in self.people.items() if t - p.last_t > self.lost_s + TIME_EPS]
        for pid in gone:
            del self.people[pid]

    def standing_hip(self, pid: int) -> float:
        """The standing hip height used for person pid (the default for an unknown id)."""
        person = self.people.get(pid)
        if person is None:
            return self.settings.standing_hip_m
        return person.standing_hip(self.settings)
