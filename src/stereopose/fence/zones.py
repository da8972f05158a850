"""Zones of the site plan (floor polygons with a height band) and the site file.

Site file (TOML, the contract in docs/formats.md, extended with optional keys):

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
    exit_s = 0.2                        # ... and outside this long to exit
    allowed = [3]                       # optional: person ids whose events are marked allowed
    expected = [1]                      # optional (work_area): persons expected to stay in it
    priority = 1                        # optional: its incidents' priority, 1-4 or a name
    rearm_s = 30.0                      # optional: a return within this long is the same incident
    voltage_kv = 10.0                   # optional (energized): margin_m from distance_table
    distance_table = "gb26860"          # optional: gb26860 (default), en50110, osha
    state = { iec104 = { ... } }        # optional (energized): live or dead (fence.power)
    [[rules]]                           # optional: behaviour rules (stereopose.behaviour)
    name = "man_down"
    type = "person_down"
    down_s = 3.0
    [postures]                          # optional: posture thresholds (PostureSettings)
    bend_deg = 35.0

All geometry here is vectorised over every joint of every person and every zone at once.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from stereopose.alarms.priority import DEFAULT_REARM_S, REARM, parse_priority
from stereopose.behaviour.definitions import (
    Rule,
    format_postures,
    format_rules,
    parse_postures,
    parse_rules,
)
from stereopose.behaviour.posture import PostureSettings
from stereopose.checks import (
    DAY_S,
    FPS,
    MAX_ZONE_VERTICES,
    MAX_ZONES,
    SITE_COORD,
    SITE_LIMIT_M,
    Range,
    named_tables,
)
from stereopose.config import read_toml
from stereopose.errors import ConfigError
from stereopose.fence.distances import DEFAULT_TABLE, approach_distance
from stereopose.fence.polygons import polygon_area, self_intersection
from stereopose.fence.power import PowerSpec, parse_power
from stereopose.skeleton import JOINTS, joint_index

KINDS = ("energized", "restricted", "work_area")
DEFAULT_ENTER_S = 0.08
DEFAULT_EXIT_S = 0.2
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
    "priority",
    "rearm_s",
    "voltage_kv",
    "distance_table",
    "state",
}
# the ranges of a zone's numbers beside their meaning: metres of approach, seconds of debounce
_ZONE_RANGES = {
    "margin_m": Range(ge=0.0, le=SITE_COORD.le),
    "enter_s": Range(ge=0.0, le=DAY_S),
    "exit_s": Range(ge=0.0, le=DAY_S),
    "dwell_s": Range(gt=0.0, le=DAY_S),
    "rearm_s": REARM,
}
_PERSON_ID = Range(integer=True, ge=0, lt=2**63)


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
    distance_table: str | None = None  # fence.distances' table (None: the default)
    power: PowerSpec | None = None  # where its live or dead state comes from (fence.power)

    def __post_init__(self) -> None:
        where = f"zone {self.name!r}"
        if self.priority is not None:
            object.__setattr__(self, "priority", parse_priority(self.priority, where))
        if self.kind not in KINDS:
            raise ConfigError(f"{where}: unknown kind {self.kind!r}; expected one of {KINDS}")
        poly = _polygon(self.polygon, where)
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
        for key, rng in _ZONE_RANGES.items():
            v = getattr(self, key)
            if v is not None:
                object.__setattr__(self, key, float(rng.check(v, f"{where}: {key}")))
        for key in ("allowed", "expected"):
            for pid in getattr(self, key):
                _PERSON_ID.check(pid, f"{where}: {key}")
        if self.expected and self.kind != "work_area":
            raise ConfigError(f"{where}: `expected` persons only make sense for a work_area")
        poly.setflags(write=False)
        object.__setattr__(self, "polygon", poly)
        object.__setattr__(self, "z", (z0, z1))


@dataclass(frozen=True)
class Site:
    zones: tuple[Zone, ...]
    fps: float | None = None  # frames per second, in [FPS_MIN, FPS_MAX]
    path: Path | None = field(default=None, compare=False)
    rules: tuple[Rule, ...] = ()  # behaviour rules (behaviour.definitions)
    postures: PostureSettings | None = None  # [postures]: the thresholds (None: defaults)

    def __post_init__(self) -> None:
        object.__setattr__(self, "rules", tuple(self.rules))
        if len(self.zones) > MAX_ZONES:
            raise ConfigError(f"{len(self.zones)} zones; a site holds at most {MAX_ZONES}")
        if self.fps is not None:
            object.__setattr__(self, "fps", float(FPS.check(self.fps, "fps")))


def _polygon(value: object, where: str) -> np.ndarray:
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


def _toml_str(text: str) -> str:
    # JSON strings are TOML basic strings, except that TOML also forbids a raw DEL
    return json.dumps(text, ensure_ascii=False).replace("\x7f", "\\u007f")


def _inline(value: Any) -> str:
    """A value as TOML (inline tables)."""
    if isinstance(value, dict):
        return (
            "{ " + ", ".join(f"{_toml_str(str(k))} = {_inline(v)}" for k, v in value.items()) + " }"
        )
    if isinstance(value, str):
        return _toml_str(value)
    if isinstance(value, bool):
        return "true" if value else "false"
    return repr(value)


def format_site(site: Site) -> str:
    """The site file's TOML text (defaults left out)."""
    lines = [f"fps = {site.fps!r}", ""] if site.fps else []
    for z in site.zones:
        pts = ", ".join(f"[{x!r}, {y!r}]" for x, y in z.polygon.tolist())
        lines += [
            "[[zones]]",
            f"name = {_toml_str(z.name)}",
            f"kind = {_toml_str(z.kind)}",
            f"polygon = [{pts}]",
            f"z = [{z.z[0]!r}, {z.z[1]!r}]",
        ]
        if len(z.joints) != len(JOINTS):
            lines.append("joints = [" + ", ".join(f'"{JOINTS[j]}"' for j in z.joints) + "]")
        for key, default in (
            ("margin_m", 0.0),
            ("dwell_s", None),
            ("enter_s", DEFAULT_ENTER_S),
            ("exit_s", DEFAULT_EXIT_S),
            ("priority", None),
            ("rearm_s", DEFAULT_REARM_S),
            ("voltage_kv", None),
        ):
            v = getattr(z, key)
            if v != default:
                lines.append(f"{key} = {v!r}")
        for key in ("allowed", "expected"):
            ids = sorted(getattr(z, key))
            if ids:
                lines.append(f"{key} = {ids}")
        if z.distance_table is not None:
            lines.append(f"distance_table = {_toml_str(z.distance_table)}")
        if z.power is not None:
            lines.append(f"state = {_inline(z.power.to_toml())}")
        lines.append("")
    lines += format_rules(site.rules)
    lines += format_postures(site.postures)
    return "\n".join(lines)


def save_site(path: str | Path, site: Site) -> None:
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(format_site(site), encoding="utf-8")
    except OSError as e:
        raise ConfigError(f"{path}: cannot write the site file: {e.strerror}") from None


def load_site(path: str | Path) -> Site:
    """Read and check a site file; every problem is an error naming the file and the zone."""
    path = Path(path)
    data = read_toml(path, "site file")
    try:
        fps = _fps(data)
        zones = _zones(data)
        rules = parse_rules(data.get("rules"), "", zones)
        postures = parse_postures(data.get("postures"), "")
        return Site(zones, fps, path, rules=rules, postures=postures)
    except ConfigError as e:
        raise ConfigError(f"{path}: {e}") from None


def _fps(data: dict[str, Any]) -> float | None:
    unknown = sorted(set(data) - {"fps", "zones", "rules", "postures"})
    if unknown:
        raise ConfigError(
            f"unknown key(s) {', '.join(unknown)}; known: fps, zones, rules, postures"
        )
    fps = data.get("fps")
    return None if fps is None else float(FPS.check(fps, "fps"))


def _number(value: Any, what: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ConfigError(f"{what}: expected a number, got {value!r}")
    try:
        return float(value)
    except OverflowError:  # an integer of hundreds of digits
        bits = int(value).bit_length()
        raise ConfigError(f"{what}: expected a number, got an integer of {bits} bits") from None


def _ids(value: Any, what: str) -> frozenset[int]:
    if not isinstance(value, list) or not all(_PERSON_ID.contains(v) for v in value):
        raise ConfigError(f"{what}: expected a list of person ids (integers >= 0), got {value!r}")
    return frozenset(value)


def _points(value: Any, where: str) -> list[list[float]]:
    """A TOML polygon: a list of [x, y] pairs of numbers (not strings, not booleans)."""
    ok = isinstance(value, list) and all(
        isinstance(p, list)
        and len(p) == 2
        and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in p)
        for p in value
    )
    if not ok:
        raise ConfigError(f"{where}: polygon must be a list of [x, y] points (numbers, metres)")
    return value


def _zones(data: dict[str, Any]) -> tuple[Zone, ...]:
    raw = data.get("zones")
    if not isinstance(raw, list) or not raw:
        raise ConfigError("no [[zones]] defined")
    if len(raw) > MAX_ZONES:
        raise ConfigError(f"{len(raw)} zones; a site holds at most {MAX_ZONES}")
    zones = []
    for name, z in named_tables(raw, "zones", "zone"):
        where = f"zone {name!r}"
        unknown = sorted(set(z) - _ZONE_KEYS)
        if unknown:
            known = ", ".join(sorted(_ZONE_KEYS))
            raise ConfigError(f"{where}: unknown key(s) {', '.join(unknown)}; known: {known}")
        for key in ("kind", "polygon", "z"):
            if key not in z:
                raise ConfigError(f"{where}: missing `{key}`")
        poly = _points(z["polygon"], where)
        if not isinstance(z["kind"], str):
            raise ConfigError(f"{where}: kind must be one of {KINDS}, got {z['kind']!r}")
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
        for key in ("margin_m", "dwell_s", "enter_s", "exit_s", "rearm_s"):
            if key in z:
                kwargs[key] = _number(z[key], f"{where}: {key}")
        if "priority" in z:
            kwargs["priority"] = parse_priority(z["priority"], where)
        kwargs |= _power(z, where)
        for key in ("allowed", "expected"):
            if key in z:
                kwargs[key] = _ids(z[key], f"{where}: {key}")
        zones.append(
            Zone(
                name=name,
                kind=z["kind"],
                polygon=poly,
                z=(_number(band[0], f"{where}: z"), _number(band[1], f"{where}: z")),
                **kwargs,
            )
        )
    return tuple(zones)


def _power(z: dict[str, Any], where: str) -> dict[str, Any]:
    """An energized zone's voltage (its margin from the distance table, unless margin_m is
    given) and state source."""
    out: dict[str, Any] = {}
    keys = [k for k in ("voltage_kv", "distance_table", "state") if k in z]
    if keys and z["kind"] != "energized":
        raise ConfigError(f"{where}: {', '.join(keys)} only for an energized zone")
    if "distance_table" in z and "voltage_kv" not in z:
        raise ConfigError(f"{where}: distance_table needs voltage_kv")
    if "voltage_kv" in z:
        table = z.get("distance_table", DEFAULT_TABLE)
        margin = approach_distance(z["voltage_kv"], table, where)
        out["voltage_kv"] = float(z["voltage_kv"])
        out["distance_table"] = table if "distance_table" in z else None
        if "margin_m" not in z:
            out["margin_m"] = margin
    if "state" in z:
        out["power"] = parse_power(z["state"], where)
    return out


class ZoneGeometry:
    """All zones' edges in padded arrays, for vectorised tests of many points.

    test(points, zones) -> inside, distance: for points (K, J, 3) each tested against one zone
    zones[k]: (K, J) inside the prism (edges and faces count as inside) and distance to it in
    metres (0 inside); NaN points are inside nothing and infinitely far.
    inside(points) / distance(points): (N, 3) points against every zone, (N, Z).
    near(boxes, reach): which people's boxes come near which zones' boxes.
    """

    def __init__(self, zones: tuple[Zone, ...]) -> None:
        self.zones = zones
        V = max(z.polygon.shape[0] for z in zones)
        # edges (Z, V, 2) from a to b; missing edges of smaller polygons are NaN (they never
        # straddle a point and have no distance)
        self.a = np.full((len(zones), V, 2), np.nan)
        self.b = np.full((len(zones), V, 2), np.nan)
        for k, zone in enumerate(zones):
            p = zone.polygon
            self.a[k, : len(p)] = p
            self.b[k, : len(p)] = np.roll(p, -1, axis=0)
        self.ab = self.b - self.a
        self.len2 = np.maximum((self.ab**2).sum(-1), 1e-18)
        with np.errstate(invalid="ignore", divide="ignore"):
            slope = self.ab[..., 0] / self.ab[..., 1]  # dx/dy, inf for horizontal edges
        # one table gathered per test: (Z, V, 7) ax, ay, by, abx, aby, 1/len2, dx/dy
        self.table = np.stack(
            [
                self.a[..., 0],
                self.a[..., 1],
                self.b[..., 1],
                self.ab[..., 0],
                self.ab[..., 1],
                1.0 / self.len2,
                slope,
            ],
            axis=-1,
        )
        self.zlo = np.array([z.z[0] for z in zones])
        self.zhi = np.array([z.z[1] for z in zones])
        self.lo = np.array([z.polygon.min(0) for z in zones])  # floor boxes (Z, 2)
        self.hi = np.array([z.polygon.max(0) for z in zones])

    def test(
        self, points: np.ndarray, zones: np.ndarray, tol: float = 1e-9
    ) -> tuple[np.ndarray, np.ndarray]:
        """Points (K, J, 3), each row against zone zones[k] -> inside (K, J), distance (K, J)."""
        px, py, pz = points[..., 0:1], points[..., 1:2], points[..., 2]  # (K, J, 1)
        tab = self.table[zones][:, None]  # (K, 1, V, 7)
        ax, ay, by, abx, aby = tab[..., 0], tab[..., 1], tab[..., 2], tab[..., 3], tab[..., 4]
        with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
            # crossing number (padding edges are NaN: they never straddle), NaN points cross
            # nothing and lie at NaN distance, turned to inf below
            dy = py - ay
            crossing = ((ay > py) != (by > py)) & (px < ax + dy * tab[..., 6])
            odd = np.logical_xor.reduce(crossing, axis=-1)
            dx = px - ax
            t = np.clip((dx * abx + dy * aby) * tab[..., 5], 0.0, 1.0)
            ex, ey = t * abx - dx, t * aby - dy
            edge_d = np.sqrt(np.fmin.reduce(ex * ex + ey * ey, axis=-1))
            floor = odd | (edge_d <= tol)
            dz = np.maximum(
                np.maximum(self.zlo[zones][:, None] - pz, pz - self.zhi[zones][:, None]), 0.0
            )
            inside = floor & (dz == 0.0)
            dist = np.hypot(np.where(floor, 0.0, edge_d), dz)
        return inside, np.where(dist == dist, dist, np.inf)

    def distance(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(N, 3) points against every zone -> inside (N, Z), distance (N, Z)."""
        Z = len(self.zones)
        inside, dist = self.test(np.broadcast_to(points[None], (Z, *points.shape)), np.arange(Z))
        return inside.T, dist.T

    def inside(self, points: np.ndarray) -> np.ndarray:
        """(N, 3) points against every zone -> (N, Z) inside."""
        return self.distance(points)[0]

    def near(self, boxes: np.ndarray, reach: np.ndarray) -> np.ndarray:
        """(P, Z) whether boxes (P, 2, 3) [min, max] come within reach (Z,) metres of each
        zone's bounding box: only those pairs can be inside or near each other."""
        lo, hi = boxes[:, 0], boxes[:, 1]
        r = reach[None]
        with np.errstate(invalid="ignore"):
            return (
                (lo[:, None, 0] <= self.hi[None, :, 0] + r)
                & (hi[:, None, 0] >= self.lo[None, :, 0] - r)
                & (lo[:, None, 1] <= self.hi[None, :, 1] + r)
                & (hi[:, None, 1] >= self.lo[None, :, 1] - r)
                & (lo[:, None, 2] <= self.zhi[None] + r)
                & (hi[:, None, 2] >= self.zlo[None] - r)
            )
