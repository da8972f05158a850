"""Validated, frozen data passed between stages.

Array conventions: pixels of the original (distorted) image for 2D, metres in the world frame
(z up, floor at z = 0) for 3D, a missing joint is NaN with confidence 0.
"""

from __future__ import annotations

import copy
import functools
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, TypedDict

import cv2
import numpy as np

from stereopose.checks import check_camera_numbers
from stereopose.errors import CalibrationError, KeypointsError
from stereopose.skeleton import NUM_JOINTS

# A JSON object as read (json.loads, a JSON Lines row, an API body): the code that reads it
# checks its values, not the type checker.
JsonDoc = Mapping[str, Any]


def _frozen(a: np.ndarray) -> np.ndarray:
    a.setflags(write=False)
    return a


def _numbers(value: object, what: str, owner: str) -> np.ndarray:
    try:
        return np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise CalibrationError(f"{owner}: {what} must be numbers, got {value!r}") from None


def _as_float_array(value: object, shape: tuple[int, ...], what: str, owner: str) -> np.ndarray:
    a = _numbers(value, what, owner)
    if a.shape != shape:
        raise CalibrationError(f"{owner}: {what} must have shape {shape}, got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise CalibrationError(f"{owner}: {what} contains NaN or infinite values: {a.tolist()}")
    return a


def rotation_matrix(rvec: np.ndarray) -> np.ndarray:
    """Rodrigues vector (3,) -> rotation matrix (3, 3)."""
    return cv2.Rodrigues(np.asarray(rvec, dtype=np.float64).reshape(3, 1))[0]


def check_rotation(R: np.ndarray, owner: str, tol: float = 1e-6) -> np.ndarray:
    """Return R (3, 3) if it is a proper rotation (orthonormal, det +1), else raise."""
    err = float(np.abs(R @ R.T - np.eye(3)).max())
    if err > tol or np.linalg.det(R) <= 0:
        raise CalibrationError(
            f"{owner}: rotation is not a rotation matrix (|R R^T - I| = {err:.2e}, "
            f"det = {np.linalg.det(R):.4f}; expected orthonormal with det = +1)"
        )
    return R


@dataclass(frozen=True, eq=False)
class Camera:
    """A calibrated pinhole camera with OpenCV lens distortion.

    matrix: (3, 3) intrinsics K in pixels (fx, fy > 0, skew 0 expected).
    distortions: (4,) k1 k2 p1 p2 or (5,) k1 k2 p1 p2 k3, OpenCV order.
    rotation: (3,) Rodrigues vector, or (3, 3) matrix, world -> camera.
    translation: (3,) metres, world -> camera: X_cam = R X_world + t.
    size: (width, height) in pixels.
    """

    name: str
    size: tuple[float, float]
    matrix: np.ndarray
    distortions: np.ndarray
    rotation: np.ndarray
    translation: np.ndarray
    fisheye: bool = False
    R: np.ndarray = field(init=False, repr=False)
    P: np.ndarray = field(init=False, repr=False)  # (3, 4) [R | t] in normalised coordinates
    center: np.ndarray = field(init=False, repr=False)  # (3,) camera centre in the world, metres

    def __post_init__(self) -> None:
        owner = f"camera {self.name!r}"
        if not isinstance(self.name, str) or not self.name:
            raise CalibrationError(f"{owner}: name must be a non-empty string")
        size = _as_float_array(self.size, (2,), "size [width, height]", owner)
        if np.any(size <= 0):
            raise CalibrationError(f"{owner}: size must be positive, got {size.tolist()}")
        K = _as_float_array(self.matrix, (3, 3), "matrix", owner)
        if K[0, 0] <= 0 or K[1, 1] <= 0:
            raise CalibrationError(
                f"{owner}: focal lengths must be positive, got fx={K[0, 0]}, fy={K[1, 1]}"
            )
        if not np.allclose(K[2], [0.0, 0.0, 1.0]) or K[1, 0] != 0:
            raise CalibrationError(f"{owner}: matrix must be [[fx, g, cx], [0, fy, cy], [0, 0, 1]]")
        dist = _numbers(self.distortions, "distortions", owner).ravel()
        if dist.shape not in ((4,), (5,)):
            raise CalibrationError(
                f"{owner}: distortions must be [k1, k2, p1, p2] or [k1, k2, p1, p2, k3], "
                f"got {dist.shape[0]} values"
            )
        dist = _as_float_array(dist, dist.shape, "distortions", owner)
        rot = _numbers(self.rotation, "rotation", owner)
        if rot.shape == (3, 3):
            R = check_rotation(_as_float_array(rot, (3, 3), "rotation", owner), owner)
            rvec = cv2.Rodrigues(R)[0].ravel()
        else:
            rvec = _as_float_array(rot.ravel() if rot.size == 3 else rot, (3,), "rotation", owner)
            R = rotation_matrix(rvec)
        t = _as_float_array(self.translation, (3,), "translation", owner)
        check_camera_numbers(size, K, dist, rvec, t, owner)
        object.__setattr__(self, "size", (float(size[0]), float(size[1])))
        object.__setattr__(self, "matrix", _frozen(K))
        object.__setattr__(self, "distortions", _frozen(dist))
        object.__setattr__(self, "rotation", _frozen(rvec))
        object.__setattr__(self, "translation", _frozen(t))
        object.__setattr__(self, "fisheye", bool(self.fisheye))
        object.__setattr__(self, "R", _frozen(R))
        object.__setattr__(self, "P", _frozen(np.hstack([R, t[:, None]])))
        object.__setattr__(self, "center", _frozen(-R.T @ t))

    @property
    def focal(self) -> float:
        """Mean focal length in pixels; converts normalised distances to pixels."""
        return float(0.5 * (self.matrix[0, 0] + self.matrix[1, 1]))

    @property
    def projection(self) -> np.ndarray:
        """H = K [R | t], (3, 4), maps world points to undistorted pixels."""
        return self.matrix @ self.P


@dataclass(frozen=True, eq=False)
class Rig:
    """Several cameras in one world frame; names are unique."""

    cameras: tuple[Camera, ...]

    def __post_init__(self) -> None:
        cams = tuple(self.cameras)
        if not cams:
            raise CalibrationError("a rig needs at least one camera")
        names = [c.name for c in cams]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise CalibrationError(f"camera names must be unique; repeated: {', '.join(dup)}")
        object.__setattr__(self, "cameras", cams)

    def __len__(self) -> int:
        return len(self.cameras)

    def __iter__(self) -> Iterator[Camera]:
        return iter(self.cameras)

    def __getitem__(self, key: int | str) -> Camera:
        if isinstance(key, str):
            for c in self.cameras:
                if c.name == key:
                    return c
            raise KeyError(f"no camera named {key!r}; cameras: {', '.join(self.names)}")
        return self.cameras[key]

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(c.name for c in self.cameras)

    def index(self, name: str) -> int:
        return self.names.index(name)

    @functools.cached_property
    def lenses(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The cameras' lenses as arrays: (C, 4) fx fy cx cy, (C, 5) k1 k2 p1 p2 k3 (k3 = 0
        where absent) and (C,) mean focal lengths, in pixels."""
        K = np.stack([c.matrix for c in self.cameras])
        fxy = np.stack([K[:, 0, 0], K[:, 1, 1], K[:, 0, 2], K[:, 1, 2]], axis=1)
        dist = np.zeros((len(self), 5))
        for i, c in enumerate(self.cameras):
            dist[i, : c.distortions.shape[0]] = c.distortions
        focal = np.array([c.focal for c in self.cameras])
        for a in (fxy, dist, focal):
            a.setflags(write=False)
        return fxy, dist, focal

    def subset(self, names: Sequence[str]) -> Rig:
        return Rig(tuple(self[n] for n in names))


@dataclass(frozen=True, eq=False)
class People2D:
    """One camera's detected people at one frame.

    keypoints: (P, 17, 3) as (x, y, conf), pixels of the original image; a missing joint has
    x = y = NaN and conf = 0 (non-finite values and conf <= 0 are normalised to that).
    boxes: optional (P, 4) x1 y1 x2 y2 pixels; scores: optional (P,) detection scores.
    """

    camera: str
    frame: int
    keypoints: np.ndarray
    boxes: np.ndarray | None = None
    scores: np.ndarray | None = None

    def __post_init__(self) -> None:
        kp = np.array(self.keypoints, dtype=np.float64)
        if kp.size == 0:
            kp = kp.reshape(0, NUM_JOINTS, 3)
        if kp.ndim != 3 or kp.shape[1:] != (NUM_JOINTS, 3):
            raise KeypointsError(
                f"camera {self.camera!r} frame {self.frame}: keypoints must have shape "
                f"(P, {NUM_JOINTS}, 3), got {kp.shape}"
            )
        bad = ~np.isfinite(kp).all(axis=-1) | (kp[..., 2] <= 0)
        kp[bad] = (np.nan, np.nan, 0.0)
        np.clip(kp[..., 2], 0.0, 1.0, out=kp[..., 2])
        object.__setattr__(self, "keypoints", _frozen(kp))
        object.__setattr__(self, "frame", int(self.frame))
        P = kp.shape[0]
        for name, shape in (("boxes", (P, 4)), ("scores", (P,))):
            v = getattr(self, name)
            if v is not None:
                a = np.array(v, dtype=np.float64).reshape(-1, *shape[1:]) if P else np.zeros(shape)
                if a.shape != shape:
                    raise KeypointsError(
                        f"camera {self.camera!r} frame {self.frame}: {name} must have shape "
                        f"{shape}, got {a.shape}"
                    )
                object.__setattr__(self, name, _frozen(a))

    def __len__(self) -> int:
        return int(self.keypoints.shape[0])

    @classmethod
    def empty(cls, camera: str, frame: int) -> People2D:
        return cls(camera, frame, np.zeros((0, NUM_JOINTS, 3)))


@dataclass(frozen=True, eq=False)
class People3D:
    """The people reconstructed at one frame.

    joints: (P, 17, 3) metres, world frame, NaN where not reconstructed.
    conf: (P, 17) in [0, 1], 0 where not reconstructed.
    ids: (P,) integer ids (per-frame indices until tracking assigns persistent ones).
    reprojection_px: (P, 17) mean reprojection error over the views used, pixels (NaN if none).
    views: (P, 17) number of camera views each joint was triangulated from.
    detections: (P, C) index of the detection used in each rig camera, -1 for none.
    predicted: (P,) true for a tracked person not seen in this frame, whose pose is predicted
        from the previous ones (default: all false).
    velocity: (P, 2) floor velocity in m/s, world x-y (default: NaN, unknown).
    t: the frame's time in seconds on the run's clock (None: frame / fps, see `time`).
    """

    frame: int
    joints: np.ndarray
    conf: np.ndarray
    ids: np.ndarray
    reprojection_px: np.ndarray
    views: np.ndarray
    detections: np.ndarray
    predicted: np.ndarray | None = None
    velocity: np.ndarray | None = None
    t: float | None = None

    def __post_init__(self) -> None:
        J = np.asarray(self.joints, dtype=np.float64)
        if J.size == 0:
            J = J.reshape(0, NUM_JOINTS, 3)
        if J.ndim != 3 or J.shape[1:] != (NUM_JOINTS, 3):
            raise ValueError(f"joints must have shape (P, {NUM_JOINTS}, 3), got {J.shape}")
        P = J.shape[0]
        per_joint = (P, NUM_JOINTS)
        set_ = object.__setattr__
        set_(self, "joints", J)
        set_(self, "frame", int(self.frame))
        for name, shape, dtype in (
            ("conf", per_joint, np.float64),
            ("ids", (P,), np.int64),
            ("reprojection_px", per_joint, np.float64),
            ("views", per_joint, np.int64),
        ):
            a = np.asarray(getattr(self, name), dtype=dtype)
            if P == 0:
                a = a.reshape(shape)
            if a.shape != shape:
                raise ValueError(f"{name} must have shape {shape}, got {a.shape}")
            set_(self, name, a)
        det = np.asarray(self.detections, dtype=np.int64)
        if det.ndim != 2 or det.shape[0] != P:
            raise ValueError(f"detections must have shape ({P}, C), got {det.shape}")
        set_(self, "detections", det)
        predicted = np.zeros(P, dtype=bool) if self.predicted is None else self.predicted
        velocity = np.full((P, 2), np.nan) if self.velocity is None else self.velocity
        for name, value, shape, dtype in (
            ("predicted", predicted, (P,), bool),
            ("velocity", velocity, (P, 2), np.float64),
        ):
            arr = np.asarray(value, dtype=dtype)
            if arr.shape != shape:
                raise ValueError(f"{name} must have shape {shape}, got {arr.shape}")
            set_(self, name, arr)

    def __len__(self) -> int:
        return int(self.joints.shape[0])

    def time(self, fps: float) -> float:
        """The frame's time in seconds: `t` where the source gave one (live cameras stamp their
        arrival time), frame / fps otherwise."""
        return self.frame / fps if self.t is None else self.t

    def where(self, mask: np.ndarray) -> People3D:
        """The people where `mask` (P,) is true, at the same frame and time."""
        m = np.asarray(mask, dtype=bool)
        return People3D(
            self.frame,
            self.joints[m],
            self.conf[m],
            self.ids[m],
            self.reprojection_px[m],
            self.views[m],
            self.detections[m],
            None if self.predicted is None else self.predicted[m],
            None if self.velocity is None else self.velocity[m],
            self.t,
        )

    def at(self, t: float) -> People3D:
        """The same people stamped with time t (the arrays shared, not copied or checked again)."""
        out = copy.copy(self)
        object.__setattr__(out, "t", float(t))
        return out

    @classmethod
    def empty(cls, frame: int, num_cameras: int) -> People3D:
        z = np.zeros((0, NUM_JOINTS))
        return cls(
            frame,
            np.zeros((0, NUM_JOINTS, 3)),
            z,
            np.zeros(0, dtype=np.int64),
            z,
            z.astype(np.int64),
            np.zeros((0, num_cameras), dtype=np.int64),
        )


class EventFields(TypedDict, total=False):
    """An Event's optional fields, as the keyword arguments of the helpers that make one."""

    joint: str | None
    distance_m: float | None
    duration_s: float | None
    position: tuple[float, float] | None
    allowed: bool
    lost: bool
    restart: bool
    camera: str | None
    reprojection_px: float | None
    baseline_px: float | None
    rule: str | None
    posture: str | None
    nearest_m: float | None
    facing_deg: float | None
    failed: str | None
    height_m: float | None
    speed_m_s: float | None
    incident: int | None
    priority: int | None
    ticket: str | None
    step: str | None
    result: dict | None
    source: str | None


@dataclass(frozen=True)
class Event:
    """One safety event of the electronic fences.

    t, frame: when it was raised (online: after the debounce); onset_t: when its condition
    began (first frame inside for `enter`, first frame outside for `exit`). type: enter, exit,
    approach, dwell or left_work_area. joint: the triggering joint (enter, approach);
    distance_m: to the zone (approach); duration_s: time inside (exit, dwell, left_work_area);
    position: the person's floor point (x, y); allowed: the person is on the zone's allowed
    list; lost: an exit closed because the person's track ended while inside; restart: an exit
    closed at start-up because the process had stopped (killed) while the person was inside.
    Camera events (kind "camera": camera_down, camera_up, calibration_drift,
    calibration_recovered) have zone "", person -1 and name their `camera`; the calibration
    events give the running and the baseline reprojection errors (pixels). Behaviour events
    (kind "behaviour", stereopose.behaviour: person_down, person_up, lone_worker, work_position,
    immobile, overreach and their `_end`s) name their `rule` and explain themselves with the
    person's `posture`, `nearest_m` (the nearest other person, lone_worker), `facing_deg` (the
    direction faced, degrees counter-clockwise from world +x) and `failed` (the conditions that
    failed, comma-separated: work_position), `height_m` (the wrist's height, overreach) and
    `speed_m_s` (how fast the hips dropped, person_down). Ticket events (kind "ticket",
    stereopose.tickets: step_done, step_out_of_order, step_wrong_position, step_timeout,
    supervisor_absent, supervisor_back, lone_in_room, lone_in_room_end, ticket_started,
    ticket_completed) name their `ticket` and `step`; a zone event in a zone an active ticket
    isolated has kind "isolated" and the ticket's id. Its JSON record (the events contract) is
    io.records.event_record.
    """

    t: float
    frame: int
    person: int
    zone: str
    kind: str
    type: str
    onset_t: float
    joint: str | None = None
    distance_m: float | None = None
    duration_s: float | None = None
    position: tuple[float, float] | None = None
    allowed: bool = False
    lost: bool = False
    restart: bool = False
    camera: str | None = None
    reprojection_px: float | None = None
    baseline_px: float | None = None
    rule: str | None = None
    posture: str | None = None
    nearest_m: float | None = None
    facing_deg: float | None = None
    failed: str | None = None
    height_m: float | None = None
    speed_m_s: float | None = None
    # the incident it belongs to (stereopose.alarms; None: an info event, or no incident book)
    # and that incident's priority (1 critical .. 4 low; None for info events)
    incident: int | None = None
    priority: int | None = None
    # ticket events (kind "ticket", stereopose.tickets) and zone events in a zone a ticket
    # isolated (kind "isolated"): the ticket's id, the step's name, and ticket_completed's result
    # (calibration_corrected / calibration_proposed: the turn and shift of the camera placed
    # again, docs/formats.md)
    ticket: str | None = None
    step: str | None = None
    result: dict | None = None
    # an energized zone's state (zones.power_state: zone_live, zone_dead, zone_unknown; a
    # dead zone's entries have kind "dead"): the breakers or switches it comes from, and for
    # zone_unknown why it is unknown
    source: str | None = None
