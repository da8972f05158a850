"""A zone of the site plan: a prism over a floor polygon, with what triggers it, its debounce,
its approach margin and where its live or dead state comes from. Checked on construction: a bad
zone is a ConfigError naming it and the value."""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from stereopose.alarms.priority import DEFAULT_REARM_S, REARM, parse_priority
from stereopose.checks import DAY_S, MAX_ZONE_VERTICES, SITE_COORD, SITE_LIMIT_M, Range
from stereopose.errors import ConfigError
from stereopose.skeleton import JOINTS
from stereopose.zones.polygons import polygon_area, self_intersection
from stereopose.zones.power import PowerSpec

__all__ = ["DEFAULT_ENTER_S", "DEFAULT_EXIT_S", "KINDS", "PERSON_ID", "Zone", "checked_polygon"]

KINDS = ("energized", "restricted", "work_area")
DEFAULT_ENTER_S = 0.08
DEFAULT_EXIT_S = 0.2
# the ranges of a zone's numbers beside their meaning: metres of approach, seconds of debounce
_ZONE_RANGES = {
    "margin_m": Range(ge=0.0, le=SITE_COORD.le),
    "enter_s": Range(ge=0.0, le=DAY_S),
    "exit_s": Range(ge=0.0, le=DAY_S),
    "dwell_s": Range(gt=0.0, le=DAY_S),
    "rearm_s": REARM,
}
PERSON_ID = Range(integer=True, ge=0, lt=2**63)


@dataclass(frozen=True, eq=False)
class Zone:
    """A prism over a floor polygon: polygon (V, 2) metres (world x-y, either orientation),
    z = (bottom, top) metres; joints: indices of the triggering joints (all 17 by default);
    priority: its incidents' (1 critical ... 4 low; None: alarms.priority's defaults by kind
    and event), rearm_s: seconds after its incident cleared within which a return is the same
    incident."""

    name: str
    kind: str
    polygon: np.ndarray
    z: tuple[float, float]
    joints: tuple[int, ...] = tuple(range(len(JOINTS)))
    margin_m: float = 0.0
    dwell_s: float | None = None
    enter_s: float = DEFAULT_ENTER_S
    exit_s: float = DEFAULT_EXIT_S
    allowed: frozenset[int] = frozenset()
    expected: frozenset[int] = frozenset()
    priority: int | None = None
    rearm_s: float = DEFAULT_REARM_S
    voltage_kv: float | None = None  # its nominal voltage (the approach margin's table row)
    distance_table: str | None = None  # zones.distances' table (None: the default)
    power: PowerSpec | None = None  # where its live or dead state comes from (zones.power)
    on_site: bool = True  # its hazards warn on site (onsite: speakers, beacons)

    def __post_init__(self) -> None:
        where = f"zone {self.name!r}"
        if self.priority is not None:
            object.__setattr__(self, "priority", parse_priority(self.priority, where))
        if self.kind not in KINDS:
            raise ConfigError(f"{where}: unknown kind {self.kind!r}; expected one of {KINDS}")
        poly = checked_polygon(self.polygon, where)
        if np.allclose(poly[0], poly[-1]) and poly.shape[0] > 3:
            poly = poly[:-1]  # a closed ring repeats its first point
        bad = self_intersection(poly)
        if bad is not None:
            raise ConfigError(f"{where}: polygon intersects itself (edges {bad[0]} and {bad[1]})")
        if abs(polygon_area(poly)) < 1e-6:
            raise ConfigError(f"{where}: polygon is degenerate (zero area)")
        band = tuple(self.z)
        if len(band) != 2:
            raise ConfigError(f"{where}: z must be [bottom, top], got {band!r}")
        z0, z1 = (float(SITE_COORD.check(v, f"{where}: z")) for v in band)
        if z0 >= z1:
            raise ConfigError(f"{where}: height band z = [{z0}, {z1}] must have bottom < top")
        for key, v in (
            ("margin_m", self.margin_m),
            ("enter_s", self.enter_s),
            ("exit_s", self.exit_s),
            ("dwell_s", self.dwell_s),
            ("rearm_s", self.rearm_s),
        ):
            if v is not None:
                object.__setattr__(self, key, float(_ZONE_RANGES[key].check(v, f"{where}: {key}")))
        for key, members in (("allowed", self.allowed), ("expected", self.expected)):
            for pid in members:
                PERSON_ID.check(pid, f"{where}: {key}")

        if self.expected and self.kind != "work_area":
            raise ConfigError(f"{where}: `expected` persons only make sense for a work_area")
        poly.setflags(write=False)
        object.__setattr__(self, "polygon", poly)
        object.__setattr__(self, "z", (z0, z1))

    def tests_alike(self, other: Zone) -> bool:
        """Whether `other` tests people as this zone does: the same prism, triggering joints,
        margin and debounce (its events may differ: priority, allowed, state source)."""
        return (
            self.kind == other.kind
            and self.polygon.shape == other.polygon.shape
            and bool(np.array_equal(self.polygon, other.polygon))
            and self.z == other.z
            and self.joints == other.joints
            and self.margin_m == other.margin_m
            and (self.enter_s, self.exit_s, self.dwell_s)
            == (other.enter_s, other.exit_s, other.dwell_s)
        )

    def same_as(self, other: Zone) -> bool:
        """Whether every field of `other` is this zone's (a site's change of it, if not)."""
        ours, others = vars(self), vars(other)
        for f in fields(self):
            mine, theirs = ours[f.name], others[f.name]
            if isinstance(mine, np.ndarray):
                if mine.shape != theirs.shape or not np.array_equal(mine, theirs):
                    return False
            elif mine != theirs:
                return False
        return True


def checked_polygon(value: object, where: str) -> np.ndarray:
    """(V, 2) finite floats within SITE_COORD, 3 <= V <= MAX_ZONE_VERTICES."""
    try:
        poly = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError, OverflowError):
        raise ConfigError(f"{where}: polygon must be a list of [x, y] points") from None
    if poly.ndim != 2 or poly.shape[1] != 2 or poly.shape[0] < 3:
        raise ConfigError(f"{where}: polygon needs at least 3 [x, y] points, got {poly.shape}")
    if poly.shape[0] > MAX_ZONE_VERTICES:
        raise ConfigError(
            f"{where}: polygon has {poly.shape[0]} points; at most {MAX_ZONE_VERTICES} allowed"
        )
    bad = ~(np.isfinite(poly) & (np.abs(poly) <= SITE_LIMIT_M))
    if bad.any():
        k, c = np.argwhere(bad)[0]
        raise ConfigError(
            f"{where}: polygon[{k}][{c}]: expected {SITE_COORD.describe()} (metres), "
            f"got {float(poly[k, c])!r}"
        )
    return poly
