"""Where people stand on the floor, which way they face, and their trajectories."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from stereopose.kernels import floor_points
from stereopose.skeleton import LEFT_HIP, RIGHT_HIP, joint_index

_LEFT_SHOULDER, _RIGHT_SHOULDER = joint_index("left_shoulder"), joint_index("right_shoulder")


def floor_position(joints: np.ndarray) -> np.ndarray:
    """(P, 17, 3) joints -> (P, 2) floor point: mid-hip x-y, or the mean of the joints seen."""
    return floor_points(np.ascontiguousarray(joints, dtype=np.float64), LEFT_HIP, RIGHT_HIP)


def heading_deg(joints: np.ndarray) -> np.ndarray:
    """(P, 17, 3) joints -> (P,) direction the body faces on the floor, degrees
    counter-clockwise from world +x (NaN when neither shoulders nor hips are known).

    The front is up x (right - left) of the shoulders, or of the hips without shoulders.
    """
    right = joints[:, _RIGHT_SHOULDER, :2] - joints[:, _LEFT_SHOULDER, :2]
    hips = joints[:, RIGHT_HIP, :2] - joints[:, LEFT_HIP, :2]
    right = np.where(np.isfinite(right).all(-1, keepdims=True), right, hips)
    return np.degrees(np.arctan2(right[:, 0], -right[:, 1]))


@dataclass
class Trajectory:
    """One person's track: first and last frame seen, time in view, path length on the floor.

    frames_seen counts frames with a measurement (predicted frames excluded); path_m sums the
    floor distance between consecutive measured positions.
    """

    id: int
    first_frame: int
    first_t: float
    last_frame: int
    last_t: float
    frames_seen: int = 0
    path_m: float = 0.0
    last_position: tuple[float, float] | None = None

    @property
    def duration_s(self) -> float:
        return self.last_t - self.first_t

    def add(self, frame: int, t: float, position: np.ndarray) -> None:
        self.last_frame, self.last_t = frame, t
        self.frames_seen += 1
        if np.isfinite(position).all():
            if self.last_position is not None:
                self.path_m += math.dist(self.last_position, position)
            self.last_position = (float(position[0]), float(position[1]))

    def as_dict(self) -> dict:
        d = asdict(self)
        d["duration_s"] = self.duration_s
        d["last_position"] = list(self.last_position) if self.last_position else None
        return d
