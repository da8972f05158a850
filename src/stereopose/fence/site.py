"""The site file: its zones (stereopose.zones), behaviour rules and posture thresholds.

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
    state = { iec104 = { ... } }        # optional (energized): live or dead (zones.power)
    [[rules]]                           # optional: behaviour rules (stereopose.behaviour)
    name = "man_down"
    type = "person_down"
    down_s = 3.0
    [postures]                          # optional: posture thresholds (PostureSettings)
    bend_deg = 35.0

`load_site` reads and checks it (a ConfigError naming the file and the value), `save_site` and
`format_site` write it back.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import TypedDict

import numpy as np

from stereopose.alarms.priority import DEFAULT_REARM_S, parse_priority
from stereopose.behaviour.definitions import (
    Rule,
    format_postures,
    format_rules,
    parse_postures,
    parse_rules,
)
from stereopose.behaviour.posture import PostureSettings
from stereopose.checks import FPS, MAX_ZONES, named_tables
from stereopose.config import parse_toml, read_toml
from stereopose.errors import ConfigError
from stereopose.onsite.settings import WarningSettings, format_warnings, parse_warnings
from stereopose.skeleton import JOINTS, joint_index
from stereopose.zones.distances import DEFAULT_TABLE, approach_distance
from stereopose.zones.power import PowerSpec, parse_power
from stereopose.zones.zone import DEFAULT_ENTER_S, DEFAULT_EXIT_S, KINDS, PERSON_ID, Zone

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
    "on_site",
}


@dataclass(frozen=True)
class Site:
    zones: tuple[Zone, ...]
    fps: float | None = None  # frames per second, in [FPS_MIN, FPS_MAX]
    path: Path | None = field(default=None, compare=False)
    rules: tuple[Rule, ...] = ()  # behaviour rules (behaviour.definitions)
    postures: PostureSettings | None = None  # [postures]: the thresholds (None: defaults)
    # [warnings], [[speakers]], [[signals]]: warnings on site (onsite.settings; None: none)
    warnings: WarningSettings | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "rules", tuple(self.rules))
        if len(self.zones) > MAX_ZONES:
            raise ConfigError(f"{len(self.zones)} zones; a site holds at most {MAX_ZONES}")
        if self.fps is not None:
            object.__setattr__(self, "fps", float(FPS.check(self.fps, "fps")))


def _toml_str(text: str) -> str:
    # JSON strings are TOML basic strings, except that TOML also forbids a raw DEL
    return json.dumps(text, ensure_ascii=False).replace("\x7f", "\\u007f")


def _inline(value: object) -> str:
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
        for key, v, default in (
            ("margin_m", z.margin_m, 0.0),
            ("dwell_s", z.dwell_s, None),
            ("enter_s", z.enter_s, DEFAULT_ENTER_S),
            ("exit_s", z.exit_s, DEFAULT_EXIT_S),
            ("priority", z.priority, None),
            ("rearm_s", z.rearm_s, DEFAULT_REARM_S),
            ("voltage_kv", z.voltage_kv, None),
        ):
            if v != default:
                lines.append(f"{key} = {v!r}")
        for key, members in (("allowed", z.allowed), ("expected", z.expected)):
            ids = sorted(members)
            if ids:
                lines.append(f"{key} = {ids}")
        if z.distance_table is not None:
            lines.append(f"distance_table = {_toml_str(z.distance_table)}")
        if z.power is not None:
            lines.append(f"state = {_inline(z.power.to_toml())}")
        if not z.on_site:
            lines.append("on_site = false")
        lines.append("")
    lines += format_rules(site.rules)
    lines += format_postures(site.postures)
    lines += format_warnings(site.warnings)
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
        return parse_site(data, path)
    except ConfigError as e:
        raise ConfigError(f"{path}: {e}") from None


def parse_site(data: object, path: Path | None = None) -> Site:
    """A site from the site file's keys (as TOML reads them, or as JSON gives them: the API's
    `site`), checked as load_site checks a file; a ConfigError naming the zone and the key."""
    if not isinstance(data, dict):
        raise ConfigError(f"a site is a table of fps, zones, rules and postures, got {data!r}")
    fps = _fps(data)
    zones = _zones(data)
    rules = parse_rules(data.get("rules"), "", zones)
    postures = parse_postures(data.get("postures"), "")
    folder = path.parent if path is not None else None
    warnings = parse_warnings(data, [z.name for z in zones], folder)
    return Site(zones, fps, path, rules=rules, postures=postures, warnings=warnings)


def site_doc(site: Site) -> dict[str, object]:
    """The site file's keys of `site` (defaults left out) as plain values: what the API gives
    and takes, and what parse_site reads back to the same site."""
    return parse_toml(format_site(site), "the site")


def site_version(site: Site) -> str:
    """A short digest of the site as its file would hold it: the same site, the same
    version, whatever its comments or key order."""
    return hashlib.sha256(format_site(site).encode("utf-8")).hexdigest()[:16]


def _fps(data: dict[str, object]) -> float | None:
    known = ("fps", "zones", "rules", "postures", "warnings", "speakers", "signals")
    unknown = sorted(set(data) - set(known))
    if unknown:
        raise ConfigError(f"unknown key(s) {', '.join(unknown)}; known: {', '.join(known)}")
    fps = data.get("fps")
    return None if fps is None else float(FPS.check(fps, "fps"))


def _number(value: object, what: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ConfigError(f"{what}: expected a number, got {value!r}")
    try:
        return float(value)
    except OverflowError:  # an integer of hundreds of digits
        bits = int(value).bit_length()
        raise ConfigError(f"{what}: expected a number, got an integer of {bits} bits") from None


def _ids(value: object, what: str) -> frozenset[int]:
    if not isinstance(value, list) or not all(PERSON_ID.contains(v) for v in value):
        raise ConfigError(f"{what}: expected a list of person ids (integers >= 0), got {value!r}")
    return frozenset(value)


class _ZoneKeys(TypedDict, total=False):
    """A zone's optional keys, as read from a site file."""

    joints: tuple[int, ...]
    margin_m: float
    dwell_s: float | None
    enter_s: float
    exit_s: float
    rearm_s: float
    priority: int | None
    allowed: frozenset[int]
    expected: frozenset[int]
    on_site: bool
    voltage_kv: float | None
    distance_table: str | None
    power: PowerSpec | None


def _points(value: object, where: str) -> np.ndarray:
    """A TOML polygon: a list of [x, y] pairs of numbers (not strings, not booleans)."""
    ok = isinstance(value, list) and all(
        isinstance(p, list)
        and len(p) == 2
        and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in p)
        for p in value
    )
    if ok:
        try:
            return np.asarray(value, dtype=np.float64)
        except OverflowError:  # an integer of hundreds of digits
            pass
    raise ConfigError(f"{where}: polygon must be a list of [x, y] points (numbers, metres)")


def _zones(data: dict[str, object]) -> tuple[Zone, ...]:
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
        kwargs: _ZoneKeys = {}
        if "joints" in z:
            js = z["joints"]
            if not isinstance(js, list) or not js:
                raise ConfigError(f"{where}: joints must be a non-empty list of joint names")
            try:
                kwargs["joints"] = tuple(sorted({joint_index(str(j)) for j in js}))
            except ValueError as e:
                raise ConfigError(f"{where}: {e}") from None
        seconds = ("margin_m", "dwell_s", "enter_s", "exit_s", "rearm_s")
        for key in seconds:
            if key in z:
                kwargs[key] = _number(z[key], f"{where}: {key}")
        if "priority" in z:
            kwargs["priority"] = parse_priority(z["priority"], where)
        kwargs.update(_power(z, where))
        if "on_site" in z:
            if not isinstance(z["on_site"], bool):
                raise ConfigError(f"{where}: on_site: expected true or false, got {z['on_site']!r}")
            kwargs["on_site"] = z["on_site"]
        if "allowed" in z:
            kwargs["allowed"] = _ids(z["allowed"], f"{where}: allowed")
        if "expected" in z:
            kwargs["expected"] = _ids(z["expected"], f"{where}: expected")
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


def _power(z: dict[str, object], where: str) -> _ZoneKeys:
    """An energized zone's voltage (its margin from the distance table, unless margin_m is
    given) and state source."""
    out: _ZoneKeys = {}
    keys = [k for k in ("voltage_kv", "distance_table", "state") if k in z]
    if keys and z["kind"] != "energized":
        raise ConfigError(f"{where}: {', '.join(keys)} only for an energized zone")
    if "distance_table" in z and "voltage_kv" not in z:
        raise ConfigError(f"{where}: distance_table needs voltage_kv")
    if "voltage_kv" in z:
        table = z.get("distance_table", DEFAULT_TABLE)
        margin = approach_distance(z["voltage_kv"], table, where)
        out["voltage_kv"] = _number(z["voltage_kv"], f"{where}: voltage_kv")
        out["distance_table"] = str(table) if "distance_table" in z else None
        if "margin_m" not in z:
            out["margin_m"] = margin
    if "state" in z:
        out["power"] = parse_power(z["state"], where)
    return out
