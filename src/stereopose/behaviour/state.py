"""What the behaviour monitor (behaviour.rules) keeps per tracked person; every rule's
condition is debounced by zones.debounce.Latch (re-exported here)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from stereopose.behaviour.posture import Posture
from stereopose.types import People3D
from stereopose.zones import ZoneGeometry
from stereopose.zones.debounce import TIME_EPS, Latch

__all__ = ["EPS", "DownState", "Latch", "Seen", "StillState", "Tracked"]

EPS = TIME_EPS  # times compared with this slack (zones.debounce)


@dataclass
class DownState:
    """person_down per person: a fall seen (fall_t), lying after it (down), the alarm raised."""

    fall_t: float | None = None
    speed: float = math.nan
    down: bool = False
    raised: bool = False
    up: Latch = field(default_factory=Latch)
    lying: Latch = field(default_factory=Latch)  # lying_s: lying without a fall seen


@dataclass
class StillState:
    """immobile per person: the mean joints since the stillness began, and since when."""

    mean: np.ndarray  # (17, 3)
    count: np.ndarray  # (17,) frames each joint's mean is of
    since: float = 0.0
    moved_since: float | None = None
    raised: bool = False


@dataclass
class Tracked:
    """What the monitor keeps of one tracked person."""

    last_seen: float
    first_seen: float
    position: tuple[float, float] | None = None
    posture: Posture | None = None
    latches: dict[str, Latch] = field(default_factory=dict)
    down: dict[str, DownState] = field(default_factory=dict)
    still: dict[str, StillState] = field(default_factory=dict)
    detail: dict[str, dict] = field(default_factory=dict)  # what an alarm's rise said


@dataclass
class Seen:
    """One person at one frame, as every rule sees them."""

    p: int
    pid: int
    person: Tracked
    people: People3D
    inside: np.ndarray | None  # (P, 17, Z) joints inside zones
    nearest: np.ndarray | None  # (P, Z) the nearest joint's distance to each zone, metres
    heading: float
    base: dict


def angle_diff(a: float, b: float) -> float:
    """a - b in degrees, in (-180, 180]."""
    d = (a - b) % 360.0
    return d - 360.0 if d > 180.0 else d


def on_floor_of(geometry: ZoneGeometry | None, k: int, xy: tuple[float, float]) -> bool:
    """Whether the floor point xy lies in zone k's polygon."""
    if geometry is None:
        return False
    zone = geometry.zones[k]
    mid = 0.5 * (zone.z[0] + zone.z[1])
    inside, _ = geometry.test(np.array([[[xy[0], xy[1], mid]]]), np.array([k]))
    return bool(inside[0, 0])
