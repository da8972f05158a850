"""Zones of the site plan (floor polygons with a height band) and the site file.

Site file (TOML, the contract of ARCHITECTURE.md, extended with optional keys):

    fps = 25.0                          # optional: the cameras' frame rate
    [[zones]]
    name = "energized_panel_A"
    kind = "energized"                  # energized | restricted | work_area
    polygon = [[0.0, 2.0], [0.9, 2.0], [0.9, 4.5], [0.0, 4.5]]   # metres, world x-y
    z = [0.0, 2.5]                      # height band, metres
    joints = ["left_wrist", "right_wrist"]   # optional; default: every joint
    margin_m = 0.5                      # optional: approach warning distance (energized)
    dwell_s = 10.0                      # optional: a dwell event after this long inside
    enter_s = 0.08                      # optional debounce: inside this long to enter ...
    exit_s = 0.3                        # ... and outside this long to exit
    allowed = [3]                       # optional: person ids whose events are marked allowed
    expected = [1]                      # optional (work_area): persons expected to stay in it

All geometry here is vectorised over every joint of every person and every zone at once.
"""

from __future__ import annotations

import math
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

from stereopose.errors import ConfigError
from stereopose.skeleton import JOINTS, joint_index

KINDS = ("energized", "restricted", "work_area")
DEFAULT_ENTER_S = 0.08
DEFAULT_EXIT_S = 0.3
_ZONE_KEYS = {
    "name",
    "kind",
    "polygon",
    "z",
    "joints",
    "margin_m",
    "dwell_s",
    "enter_s",
    "exit_s",
    "allowed",
    "expected",
}


@dataclass(frozen=True, eq=False)
class Zone:
    """A prism over a floor polygon: polygon (V, 2) metres (world x-y, either orientation),
    z = (bottom, top) metres; joints: indices of the triggering joints (all 17 by default)."""

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

    def __post_init__(self) -> None:
        where = f"zone {self.name!r}"
        if self.kind not in KINDS:
            raise ConfigError(f"{where}: unknown kind {self.kind!r}; expected one of {KINDS}")
        poly = np.asarray(self.polygon, dtype=np.float64)
        if poly.ndim != 2 or poly.shape[1] != 2 or poly.shape[0] < 3:
            raise ConfigError(f"{where}: polygon needs at least 3 [x, y] points, got {poly.shape}")
        if not np.isfinite(poly).all():
            raise ConfigError(f"{where}: polygon has a non-finite coordinate")
        if np.allclose(poly[0], poly[-1]) and poly.shape[0] > 3:
            poly = poly[:-1]  # a closed ring repeats its first point
        bad = self_intersection(poly)
        if bad is not None:
            raise ConfigError(f"{where}: polygon intersects itself (edges {bad[0]} and {bad[1]})")
        if abs(polygon_area(poly)) < 1e-6:
            raise ConfigError(f"{where}: polygon is degenerate (zero area)")
        z0, z1 = (float(v) for v in self.z)
        if not (math.isfinite(z0) and math.isfinite(z1)) or z0 >= z1:
            raise ConfigError(f"{where}: height band z = [{z0}, {z1}] must have bottom < top")
        for key in ("margin_m", "enter_s", "exit_s"):
            v = getattr(self, key)
            if not (math.isfinite(v) and v >= 0):
                raise ConfigError(f"{where}: {key} must be >= 0, got {v}")
        if self.dwell_s is not None and not self.dwell_s > 0:
            raise ConfigError(f"{where}: dwell_s must be > 0, got {self.dwell_s}")
        if self.expected and self.kind != "work_area":
            raise ConfigError(f"{where}: `expected` persons only make sense for a work_area")
        poly.setflags(write=False)
        object.__setattr__(self, "polygon", poly)
        object.__setattr__(self, "z", (z0, z1))


@dataclass(frozen=True)
class Site:
    zones: tuple[Zone, ...]
    fps: float | None = None
    path: Path | None = field(default=None, compare=False)


def polygon_area(poly: np.ndarray) -> float:
    """Signed area (shoelace), positive for counter-clockwise vertices."""
    x, y = poly[:, 0], poly[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(np.roll(x, -1), y))


def _cross(o, a, b) -> float:
    return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])


def _segments_cross(p1, p2, q1, q2) -> bool:
    """Whether segments p1p2 and q1q2 share a point (touching and overlapping included)."""
    d1, d2 = _cross(q1, q2, p1), _cross(q1, q2, p2)
    d3, d4 = _cross(p1, p2, q1), _cross(p1, p2, q2)
    if ((d1 > 0) != (d2 > 0)) and ((d3 > 0) != (d4 > 0)) and 0 not in (d1, d2, d3, d4):
        return True

    def on(a, b, c, d) -> bool:  # c on segment ab, given collinear (d == 0)
        return (
            d == 0
            and min(a[0], b[0]) <= c[0] <= max(a[0], b[0])
            and min(a[1], b[1]) <= c[1] <= max(a[1], b[1])
        )

    return on(q1, q2, p1, d1) or on(q1, q2, p2, d2) or on(p1, p2, q1, d3) or on(p1, p2, q2, d4)


def self_intersection(poly: np.ndarray) -> tuple[int, int] | None:
    """The first pair of non-adjacent edges (i, j) that meet, or None for a simple polygon."""
    V = poly.shape[0]
    for i in range(V):
        a, b = poly[i], poly[(i + 1) % V]
        for j in range(i + 1, V):
            if j == i + 1 or (i == 0 and j == V - 1):
                continue  # adjacent edges share a vertex by construction
            if _segments_cross(a, b, poly[j], poly[(j + 1) % V]):
                return i, j
    return None


def load_site(path: str | Path) -> Site:
    """Read and check a site file; every problem is an error naming the file and the zone."""
    path = Path(path)
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ConfigError(f"{path}: site file not found") from None
    except (OSError, UnicodeDecodeError) as e:
        raise ConfigError(f"{path}: cannot read site file: {e}") from None
    except tomllib.TOMLDecodeError as e:
        raise ConfigError(f"{path}: invalid TOML: {e}") from None
    try:
        return Site(_zones(data), _fps(data), path)
    except ConfigError as e:
        raise ConfigError(f"{path}: {e}") from None


def _fps(data: dict[str, Any]) -> float | None:
    unknown = sorted(set(data) - {"fps", "zones"})
    if unknown:
        raise ConfigError(f"unknown key(s) {', '.join(unknown)}; known: fps, zones")
    fps = data.get("fps")
    if fps is None:
        return None
    if isinstance(fps, bool) or not isinstance(fps, (int, float)) or not fps > 0:
        raise ConfigError(f"fps must be a positive number, got {fps!r}")
    return float(fps)


def _number(value: Any, what: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ConfigError(f"{what}: expected a number, got {value!r}")
    return float(value)


def _ids(value: Any, what: str) -> frozenset[int]:
    if not isinstance(value, list) or not all(
        isinstance(v, int) and not isinstance(v, bool) for v in value
    ):
        raise ConfigError(f"{what}: expected a list of person ids, got {value!r}")
    return frozenset(value)


def _zones(data: dict[str, Any]) -> tuple[Zone, ...]:
    raw = data.get("zones")
    if not isinstance(raw, list) or not raw:
        raise ConfigError("no [[zones]] defined")
    zones, names = [], set()
    for k, z in enumerate(raw):
        if not isinstance(z, dict):
            raise ConfigError(f"zones[{k}]: expected a table")
        name = z.get("name")
        if not isinstance(name, str) or not name:
            raise ConfigError(f"zones[{k}]: missing `name`")
        where = f"zone {name!r}"
        if name in names:
            raise ConfigError(f"{where}: the name is used twice")
        names.add(name)
        unknown = sorted(set(z) - _ZONE_KEYS)
        if unknown:
            known = ", ".join(sorted(_ZONE_KEYS))
            raise ConfigError(f"{where}: unknown key(s) {', '.join(unknown)}; known: {known}")
        for key in ("kind", "polygon", "z"):
            if key not in z:
                raise ConfigError(f"{where}: missing `{key}`")
        try:
            poly = np.array(z["polygon"], dtype=np.float64)
        except (TypeError, ValueError):
            raise ConfigError(f"{where}: polygon must be a list of [x, y] points") from None
        band = z["z"]
        if not isinstance(band, list) or len(band) != 2:
            raise ConfigError(f"{where}: z must be [bottom, top], got {band!r}")
        kwargs: dict[str, Any] = {}
        if "joints" in z:
            js = z["joints"]
            if not isinstance(js, list) or not js:
                raise ConfigError(f"{where}: joints must be a non-empty list of joint names")
            try:
                kwargs["joints"] = tuple(sorted({joint_index(str(j)) for j in js}))
            except ValueError as e:
                raise ConfigError(f"{where}: {e}") from None
        for key in ("margin_m", "dwell_s", "enter_s", "exit_s"):
            if key in z:
                kwargs[key] = _number(z[key], f"{where}: {key}")
        for key in ("allowed", "expected"):
            if key in z:
                kwargs[key] = _ids(z[key], f"{where}: {key}")
        zones.append(
            Zone(
                name=name,
                kind=str(z["kind"]),
                polygon=poly,
                z=(_number(band[0], f"{where}: z"), _number(band[1], f"{where}: z")),
                **kwargs,
            )
        )
    return tuple(zones)


class ZoneGeometry:
    """All zones' edges in flat arrays, for one vectorised test of many points.

    inside(points) -> (N, Z) bool: point in zone's prism (edges and faces count as inside).
    distance(points) -> (N, Z) metres from each point to each prism (0 inside).
    """

    def __init__(self, zones: tuple[Zone, ...]) -> None:
        self.zones = zones
        a, b, owner = [], [], []
        for k, zone in enumerate(zones):
            p = zone.polygon
            a.append(p)
            b.append(np.roll(p, -1, axis=0))
            owner.append(np.full(p.shape[0], k))
        self.a = np.concatenate(a)  # (E, 2) edge starts
        self.b = np.concatenate(b)
        self.ab = self.b - self.a
        self.len2 = np.maximum((self.ab**2).sum(-1), 1e-18)
        self.owner = np.concatenate(owner)
        self.starts = np.cumsum([0] + [z.polygon.shape[0] for z in zones])[:-1]
        self.zlo = np.array([z.z[0] for z in zones])
        self.zhi = np.array([z.z[1] for z in zones])

    def _edges(self, xy: np.ndarray):
        """(N, E) crossing flags (ray to +x) and squared distances to each edge."""
        px, py = xy[:, 0:1], xy[:, 1:2]
        ax, ay, bx, by = self.a[:, 0], self.a[:, 1], self.b[:, 0], self.b[:, 1]
        straddle = (ay > py) != (by > py)
        with np.errstate(invalid="ignore", divide="ignore"):
            x_at = ax + (py - ay) * (bx - ax) / (by - ay)
        crossing = straddle & (px < x_at)
        t = ((px - ax) * self.ab[:, 0] + (py - ay) * self.ab[:, 1]) / self.len2
        t = np.clip(t, 0.0, 1.0)
        dx, dy = ax + t * self.ab[:, 0] - px, ay + t * self.ab[:, 1] - py
        return crossing, dx * dx + dy * dy

    def floor_inside(self, xy: np.ndarray, tol: float = 1e-9) -> tuple[np.ndarray, np.ndarray]:
        """(N, Z) whether floor points (N, 2) lie in each polygon (boundary included), and
        (N, Z) their distance to each polygon's boundary."""
        crossing, d2 = self._edges(xy)
        odd = np.add.reduceat(crossing.astype(np.int64), self.starts, axis=1) % 2 == 1
        edge_d = np.sqrt(np.minimum.reduceat(d2, self.starts, axis=1))
        return odd | (edge_d <= tol), edge_d

    def inside(self, points: np.ndarray) -> np.ndarray:
        """(N, 3) points -> (N, Z) inside each prism; NaN points are inside nothing."""
        ok = np.isfinite(points).all(-1)
        out = np.zeros((points.shape[0], len(self.zones)), dtype=bool)
        if ok.any():
            p = points[ok]
            floor, _ = self.floor_inside(p[:, :2])
            z = p[:, 2:3]
            out[ok] = floor & (z >= self.zlo) & (z <= self.zhi)
        return out

    def distance(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(N, 3) points -> (N, Z) inside flags and distances (metres, 0 inside) to each prism;
        NaN points are inside nothing and infinitely far."""
        ok = np.isfinite(points).all(-1)
        Z = len(self.zones)
        inside = np.zeros((points.shape[0], Z), dtype=bool)
        dist = np.full((points.shape[0], Z), np.inf)
        if ok.any():
            p = points[ok]
            floor, edge_d = self.floor_inside(p[:, :2])
            z = p[:, 2:3]
            dz = np.maximum(np.maximum(self.zlo - z, z - self.zhi), 0.0)
            dh = np.where(floor, 0.0, edge_d)
            inside[ok] = floor & (dz == 0.0)
            dist[ok] = np.hypot(dh, dz)
        return inside, dist
