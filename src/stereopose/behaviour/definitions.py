"""The behaviour rules of the site file: `[[rules]]` tables beside the zones.

    [[rules]]
    name = "man_down"
    type = "person_down"        # person_down | lone_worker | work_position | immobile | overreach
    down_s = 3.0                # the type's parameters (see each class below)
    priority = 1                # optional, every type: its incidents' priority, 1-4 or a name
    rearm_s = 30.0              # optional, every type: a return within this long, same incident

Every rule has a unique `name` and a `type`; each type has its own keys, and a key the type does
not know, a missing required key, a number out of its range or a zone the site does not have is a
ConfigError naming the rule (and, through fence.site.load_site, the file).

The rules are frozen dataclasses, one per type; `Rule` is any of them. The monitor that applies
them is behaviour.rules.BehaviourMonitor.
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import MISSING, dataclass, field, fields
from typing import Any, ClassVar, Protocol

from stereopose.alarms.priority import DEFAULT_REARM_S, REARM, parse_priority
from stereopose.behaviour.posture import POSTURES, PostureSettings
from stereopose.checks import DAY_S, SITE_LIMIT_M, Range, named_tables
from stereopose.errors import ConfigError
from stereopose.skeleton import JOINTS, LEFT_WRIST, RIGHT_WRIST, joint_index


class Zone(Protocol):
    """What the rules need of a zone (zones.Zone, which reads the site file and
    imports this module)."""

    @property
    def name(self) -> str: ...

    @property
    def kind(self) -> str: ...


__all__ = [
    "ALARM_TYPES",
    "BEHAVIOUR_KIND",
    "MAX_RULES",
    "RULE_TYPES",
    "ImmobileRule",
    "LoneWorkerRule",
    "OverreachRule",
    "PersonDownRule",
    "Rule",
    "WorkPositionRule",
    "format_postures",
    "format_rules",
    "parse_postures",
    "parse_rules",
    "watched_zones",
]

BEHAVIOUR_KIND = "behaviour"  # the `kind` of every behaviour event
# the event types that are alarms (the others say that one has ended)
ALARM_TYPES = frozenset({"person_down", "lone_worker", "work_position", "immobile", "overreach"})
MAX_RULES = 100

_SECONDS = Range(ge=0.0, le=DAY_S)
_POSITIVE_S = Range(gt=0.0, le=DAY_S)
_METRES = Range(gt=0.0, le=SITE_LIMIT_M)
_HEIGHT = Range(ge=-SITE_LIMIT_M, le=SITE_LIMIT_M)
_SPEED = Range(gt=0.0, le=100.0)  # m/s
_DEGREES = Range(ge=-360.0, le=360.0)
_TOLERANCE = Range(gt=0.0, le=180.0)


@dataclass(frozen=True)
class _Alarming:
    """What every rule has for its incidents (stereopose.alarms): priority (1 critical ... 4
    low; None: the default of its type) and rearm_s (a return within this long after its
    incident cleared is the same incident)."""

    priority: int | None = field(default=None, kw_only=True)
    rearm_s: float = field(default=DEFAULT_REARM_S, kw_only=True)

    def __post_init__(self) -> None:
        if self.priority is not None:
            name = getattr(self, "name", "")
            object.__setattr__(self, "priority", parse_priority(self.priority, f"rule {name!r}"))


_ALARMING = frozenset(f.name for f in fields(_Alarming))


@dataclass(frozen=True)
class PersonDownRule(_Alarming):
    """A fall and the person not up again: the hips dropping faster than fall_speed_m_s (peak
    downward speed over 0.2 s, within the last second) to below floor_m (the trunk's height
    above the floor under the body, metres), the body lying within settle_s after, and not up
    (standing, walking or bending for up_s) down_s after the fall -> one `person_down`;
    `person_up` once they rise. lying_s (default: off): someone lying that long without a fall
    seen (it happened out of view, or before the start) -> `person_down` too; it would also
    alarm for work done lying under equipment."""

    type: ClassVar[str] = "person_down"
    name: str
    down_s: float = 3.0
    up_s: float = 1.0
    fall_speed_m_s: float = 1.0
    floor_m: float = 0.4
    settle_s: float = 2.0
    lying_s: float | None = None


@dataclass(frozen=True)
class LoneWorkerRule(_Alarming):
    """Someone inside one of `zones` or within approach_m of it (any joint) with nobody else
    within buddy_m (floor distance) for lone_s -> `lone_worker`; `lone_worker_end` once they
    have had company or left for exit_s."""

    type: ClassVar[str] = "lone_worker"
    name: str
    zones: tuple[str, ...]
    buddy_m: float = 3.0
    lone_s: float = 10.0
    approach_m: float = 1.0
    exit_s: float = 2.0


@dataclass(frozen=True)
class WorkPositionRule(_Alarming):
    """While a wrist is inside one of `energized` (default: every energized zone), the person
    must stand in the work area `zone` (floor position), face facing_deg (degrees counter-
    clockwise from world +x) within tolerance_deg and, when `postures` is given, hold one of
    them. Any condition failing for enter_s -> `work_position` naming which (`failed`:
    position, facing, posture); `work_position_end` once all hold or the hand is out for
    exit_s."""

    type: ClassVar[str] = "work_position"
    name: str
    zone: str
    facing_deg: float
    tolerance_deg: float = 30.0
    postures: tuple[str, ...] | None = None
    energized: tuple[str, ...] = ()
    enter_s: float = 0.5
    exit_s: float = 0.5


@dataclass(frozen=True)
class ImmobileRule(_Alarming):
    """A person none of whose joints moves more than still_m (from their mean position since
    the stillness began) for immobile_s -> `immobile`; `immobile_end` once a joint has moved
    for move_s."""

    type: ClassVar[str] = "immobile"
    name: str
    immobile_s: float
    still_m: float = 0.15
    move_s: float = 0.2


@dataclass(frozen=True)
class OverreachRule(_Alarming):
    """One of `joints` (default: the wrists) above max_height_m for enter_s -> `overreach`;
    `overreach_end` once below for exit_s. zones (default: anywhere): only while the person
    is in one of them or within approach_m of it (a barrier under overhead conductors)."""

    type: ClassVar[str] = "overreach"
    name: str
    max_height_m: float
    joints: tuple[int, ...] = (LEFT_WRIST, RIGHT_WRIST)
    enter_s: float = 0.2
    exit_s: float = 0.5
    zones: tuple[str, ...] = ()
    approach_m: float = 1.0


Rule = PersonDownRule | LoneWorkerRule | WorkPositionRule | ImmobileRule | OverreachRule
RULE_TYPES: dict[str, type] = {
    cls.type: cls
    for cls in (PersonDownRule, LoneWorkerRule, WorkPositionRule, ImmobileRule, OverreachRule)
}


def watched_zones(rule: Rule, zones: Iterable[Zone]) -> tuple[str, ...] | None:
    """The zones a rule watches, in order (None: the whole site): a work position's energized
    zones (default: every energized zone) and its work area; the zones of a lone-worker or
    overreach rule (none given: the whole site)."""
    names: list[str] = []
    if isinstance(rule, LoneWorkerRule | OverreachRule):
        names += rule.zones
    elif isinstance(rule, WorkPositionRule):
        names += rule.energized or [z.name for z in zones if z.kind == "energized"]
        names.append(rule.zone)
    return tuple(dict.fromkeys(names)) or None


# each numeric key's range, beside its meaning
_RANGES: dict[str, Range] = {
    "down_s": _POSITIVE_S,
    "up_s": _SECONDS,
    "fall_speed_m_s": _SPEED,
    "floor_m": _METRES,
    "settle_s": _POSITIVE_S,
    "lying_s": _POSITIVE_S,
    "buddy_m": _METRES,
    "lone_s": _SECONDS,
    "approach_m": Range(ge=0.0, le=SITE_LIMIT_M),
    "exit_s": _SECONDS,
    "enter_s": _SECONDS,
    "facing_deg": _DEGREES,
    "tolerance_deg": _TOLERANCE,
    "immobile_s": _POSITIVE_S,
    "still_m": _METRES,
    "move_s": _SECONDS,
    "max_height_m": _HEIGHT,
    "rearm_s": REARM,
}


def _fields(rule: Any) -> list:
    """A rule type's fields, the type's own first, then priority and rearm_s."""
    own = [f for f in fields(rule) if f.name not in _ALARMING]
    return own + [f for f in fields(rule) if f.name in _ALARMING]


def _keys(cls: type) -> tuple[list[str], list[str]]:
    """(required, optional) keys of a rule type, besides name and type."""
    required, optional = [], []
    for f in _fields(cls):
        if f.name != "name":
            (required if f.default is MISSING else optional).append(f.name)
    return required, optional


def _names(value: object, where: str, key: str) -> tuple[str, ...]:
    if not isinstance(value, list) or not value or not all(isinstance(v, str) and v for v in value):
        raise ConfigError(f"{where}: {key} must be a non-empty list of names, got {value!r}")
    return tuple(dict.fromkeys(value))


def _zone_names(
    names: Sequence[str], where: str, key: str, zones: Mapping[str, Zone], kind: str | None
) -> None:
    for n in names:
        if n not in zones:
            known = ", ".join(sorted(zones)) or "none"
            raise ConfigError(f"{where}: {key}: no zone named {n!r}; zones: {known}")
        if kind is not None and zones[n].kind != kind:
            raise ConfigError(
                f"{where}: {key}: zone {n!r} is {zones[n].kind}; expected a {kind} zone"
            )


def _value(key: str, value: object, where: str) -> Any:
    """One parameter, checked and converted."""
    if key in _RANGES:
        rng = _RANGES[key]
        return float(rng.check(value, f"{where}: {key}"))
    if key == "priority":
        return parse_priority(value, where)
    if key in ("zones", "energized"):
        return _names(value, where, key)
    if key == "zone":
        if not isinstance(value, str) or not value:
            raise ConfigError(f"{where}: zone must be a zone's name, got {value!r}")
        return value
    if key == "postures":
        names = _names(value, where, key)
        bad = [p for p in names if p not in POSTURES]
        if bad:
            raise ConfigError(
                f"{where}: postures: unknown posture(s) {', '.join(map(repr, bad))}; "
                f"known: {', '.join(POSTURES)}"
            )
        return names
    if key == "joints":
        names = _names(value, where, key)
        try:
            return tuple(sorted({joint_index(n) for n in names}))
        except ValueError as e:
            raise ConfigError(f"{where}: joints: {e}") from None
    raise AssertionError(key)  # every field of a rule type is handled above


def parse_rules(
    items: Sequence[Mapping[str, object]] | None, where: str, zones: Sequence[Zone]
) -> tuple[Rule, ...]:
    """The rules of a site file's `[[rules]]` (None or [] -> none); `where` prefixes every
    message (e.g. the file); zones: the site's zones, which the rules name."""
    lead = f"{where}: " if where else ""
    if items is None:
        return ()
    if not isinstance(items, list):
        raise ConfigError(f"{lead}rules must be [[rules]] tables")
    if len(items) > MAX_RULES:
        raise ConfigError(f"{lead}{len(items)} rules; a site holds at most {MAX_RULES}")
    by_name = {z.name: z for z in zones}
    out: list[Rule] = []
    for name, item in named_tables(items, "rules", "rule", lead):
        here = f"{lead}rule {name!r}"
        kind = item.get("type")
        if kind is None:
            raise ConfigError(f"{here}: missing `type`; one of {', '.join(RULE_TYPES)}")
        if kind not in RULE_TYPES:
            raise ConfigError(
                f"{here}: unknown type {kind!r}; expected one of {', '.join(RULE_TYPES)}"
            )
        cls = RULE_TYPES[kind]
        required, optional = _keys(cls)
        unknown = sorted(set(item) - {"name", "type", *required, *optional})
        if unknown:
            known = ", ".join(["name", "type", *required, *optional])
            raise ConfigError(f"{here}: unknown key(s) {', '.join(unknown)}; {kind} knows {known}")
        missing = [key for key in required if key not in item]
        if missing:
            raise ConfigError(f"{here}: missing {', '.join(f'`{m}`' for m in missing)}")
        given = [key for key in (*required, *optional) if key in item]
        kwargs = {key: _value(key, item[key], here) for key in given}
        rule = cls(name=name, **kwargs)
        _check_zones(rule, here, by_name)
        out.append(rule)
    return tuple(out)


def _check_zones(rule: Rule, where: str, zones: Mapping[str, Zone]) -> None:
    if isinstance(rule, (LoneWorkerRule, OverreachRule)):
        _zone_names(rule.zones, where, "zones", zones, None)
    elif isinstance(rule, WorkPositionRule):
        _zone_names([rule.zone], where, "zone", zones, "work_area")
        _zone_names(rule.energized, where, "energized", zones, "energized")
        if not rule.energized and not any(z.kind == "energized" for z in zones.values()):
            raise ConfigError(f"{where}: the site has no energized zone to watch the hands in")


def _toml(value: object) -> str:
    if isinstance(value, str):
        return json.dumps(value, ensure_ascii=False).replace("\x7f", "\\u007f")
    if isinstance(value, tuple):
        return "[" + ", ".join(_toml(v) for v in value) + "]"
    return repr(value)


def format_rules(rules: Sequence[Rule]) -> list[str]:
    """The `[[rules]]` tables' TOML lines (defaults left out)."""
    lines: list[str] = []
    for rule in rules:
        lines += ["[[rules]]", f"name = {_toml(rule.name)}", f"type = {_toml(rule.type)}"]
        for f in _fields(rule):
            if f.name == "name":
                continue
            value = getattr(rule, f.name)
            if f.default is not MISSING and value == f.default:
                continue
            if f.name == "joints":
                value = tuple(JOINTS[j] for j in value)
            lines.append(f"{f.name} = {_toml(value)}")
        lines.append("")
    return lines


# the ranges of the site's [postures] keys (PostureSettings), beside their units
_DEG = Range(gt=0.0, le=180.0)
_POSTURE_RANGES: dict[str, Range] = {
    "standing_hip_m": Range(gt=0.0, le=3.0),
    "hip_quantile": Range(gt=0.0, le=1.0),
    "min_samples": Range(integer=True, ge=1, le=100_000),
    "low_hip_ratio": Range(gt=0.0, lt=1.0),
    "ankle_m": Range(ge=0.0, le=0.5),
    "min_standing_hip_m": Range(ge=0.0, le=3.0),
    "lying_height_m": Range(gt=0.0, le=3.0),
    "lying_deg": _DEG,
    "lying_thigh_deg": _DEG,
    "bend_deg": _DEG,
    "upright_deg": _DEG,
    "knee_bent_deg": _DEG,
    "crouch_thigh_deg": _DEG,
    "walk_speed_m_s": Range(gt=0.0, le=10.0),
    "walk_window_s": Range(gt=0.0, le=60.0),
    "drop_dt_s": Range(gt=0.0, le=10.0),
    "drop_window_s": Range(gt=0.0, le=60.0),
    "raised_m": Range(ge=-1.0, le=2.0),
    "raised_shoulder_m": Range(ge=-1.0, le=2.0),
    "reach_m": Range(gt=0.0, le=3.0),
    "min_joints": Range(integer=True, ge=1, le=17),
}
assert set(_POSTURE_RANGES) == {f.name for f in fields(PostureSettings)}


def parse_postures(table: object, where: str) -> PostureSettings | None:
    """The site file's optional `[postures]` table: PostureSettings' thresholds to change for
    this site (None: the defaults). An unknown key or a value out of range is a ConfigError
    naming the key."""
    lead = f"{where}: " if where else ""
    if table is None:
        return None
    if not isinstance(table, dict):
        raise ConfigError(f"{lead}postures must be a [postures] table")
    unknown = sorted(set(table) - set(_POSTURE_RANGES))
    if unknown:
        raise ConfigError(
            f"{lead}[postures]: unknown key(s) {', '.join(unknown)}; "
            f"known: {', '.join(_POSTURE_RANGES)}"
        )
    kwargs = {}
    for key, value in table.items():
        rng = _POSTURE_RANGES[key]
        v = rng.check(value, f"{lead}[postures] {key}")
        kwargs[key] = int(v) if rng.integer else float(v)
    return PostureSettings(**kwargs)


def format_postures(settings: PostureSettings | None) -> list[str]:
    """The `[postures]` table's TOML lines (only the keys that differ from the defaults)."""
    if settings is None:
        return []
    default = PostureSettings()
    lines = [
        f"{f.name} = {getattr(settings, f.name)!r}"
        for f in fields(settings)
        if getattr(settings, f.name) != getattr(default, f.name)
    ]
    return ["[postures]", *lines, ""] if lines else []
