"""People's trajectories on the floor (where they stand and face: skeleton.floor_position,
skeleton.heading_deg)."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import TYPE_CHECKING

from stereopose.skeleton import floor_position, heading_deg

if TYPE_CHECKING:
    import numpy as np

__all__ = ["Trajectory", "floor_position", "heading_deg"]


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

    def add(self, frame: int, t: float, position: np.ndarray | tuple[float, float]) -> None:
        """A measured frame; position: floor x, y (NaN: unknown)."""
        self.last_frame, self.last_t = frame, t
        self.frames_seen += 1
        x, y = float(position[0]), float(position[1])
        if math.isfinite(x) and math.isfinite(y):
            if self.last_position is not None:
                self.path_m += math.dist(self.last_position, (x, y))
            self.last_position = (x, y)

    def as_dict(self) -> dict:
        d = asdict(self)
        d["duration_s"] = self.duration_s
        d["last_position"] = list(self.last_position) if self.last_position else None
        return d
