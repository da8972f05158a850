"""Priorities of incidents, their defaults, and the site file's `priority` and `rearm_s`.

Four levels, 1 the most urgent (the ISA-18.2 habit: few levels, unequal in number):

    1 critical  a person inside an energized zone; a person down
    2 high      a hand or body approaching an energized zone; a lone worker
    3 medium    a wrong work position, someone immobile, an overreach; entering a restricted
                zone, a dwell, leaving one's work area
    4 low       diagnostics: a camera down, a calibration drifting, the service stalled

A zone's or a rule's `priority` in the site file (1-4, or its name) replaces the default for
every incident of that zone or rule. An incident's priority is the most urgent of its
occurrences' (an approach that becomes an entry rises from high to critical).

`rearm_s` (default 30 s, per zone and per rule): a hazard that comes back within this long
after its incident cleared is an occurrence of the same incident, not a new one.
"""

from __future__ import annotations

import numbers
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Protocol

from stereopose.alarms.levels import BEHAVIOUR_ALARMS, HazardKey
from stereopose.checks import DAY_S, Range
from stereopose.errors import ConfigError

__all__ = [
    "CRITICAL",
    "DEFAULT_REARM_S",
    "HIGH",
    "LOW",
    "MEDIUM",
    "PRIORITIES",
    "PRIORITY_NAMES",
    "REARM",
    "AlarmSettings",
    "Tuning",
    "default_priority",
    "parse_priority",
    "parse_rearm",
]

CRITICAL, HIGH, MEDIUM, LOW = 1, 2, 3, 4
PRIORITY_NAMES = {CRITICAL: "critical", HIGH: "high", MEDIUM: "medium", LOW: "low"}
PRIORITIES = tuple(PRIORITY_NAMES)
_BY_NAME = {name: p for p, name in PRIORITY_NAMES.items()}
DEFAULT_REARM_S = 30.0
REARM = Range(ge=0.0, le=DAY_S)  # seconds
_PRIORITY = Range(integer=True, ge=CRITICAL, le=LOW)

# behaviour alarms by type: a fall is as urgent as a hand in a live panel
_RULE_PRIORITY = {
    "person_down": CRITICAL,
    "lone_worker": HIGH,
    "work_position": MEDIUM,
    "immobile": MEDIUM,
    "overreach": MEDIUM,
}
assert set(_RULE_PRIORITY) == BEHAVIOUR_ALARMS


def default_priority(kind: str, type_: str) -> int:
    """The priority of an event of zone kind (or event kind: behaviour, camera, service)
    `kind` and type `type_` when the site sets none."""
    if kind == "energized" and type_ == "enter":
        return CRITICAL
    if kind == "energized" and type_ == "approach":
        return HIGH
    if type_ in _RULE_PRIORITY:
        return _RULE_PRIORITY[type_]
    if type_ in ("supervisor_absent", "lone_in_room"):
        return HIGH
    if kind in ("camera", "service") or type_ in ("camera_down", "calibration_drift"):
        return LOW
    return MEDIUM  # restricted entries, dwells, leaving a work area


def parse_priority(value: object, where: str) -> int:
    """A site file's `priority`: 1-4 or critical / high / medium / low -> 1-4; anything else
    a ConfigError naming `where` and the value."""
    if isinstance(value, str):
        p = _BY_NAME.get(value.strip().lower())
        if p is not None:
            return p
    elif _PRIORITY.contains(value) and isinstance(value, numbers.Integral):
        return int(value)
    names = ", ".join(PRIORITY_NAMES.values())
    raise ConfigError(
        f"{where}: priority: expected an integer in [1, 4] or one of {names}, got {value!r}"
    )


def parse_rearm(value: object, where: str) -> float:
    """A site file's `rearm_s`: seconds in [0, 86400]."""
    return float(REARM.check(value, f"{where}: rearm_s"))


@dataclass(frozen=True)
class Tuning:
    """One zone's or rule's settings: priority (None: the defaults by event) and rearm_s."""

    priority: int | None = None
    rearm_s: float = DEFAULT_REARM_S


class Tuned(Protocol):
    """A zone or a behaviour rule, as the incident book reads it (zones.Zone, a rule of
    behaviour.definitions)."""

    @property
    def name(self) -> str: ...

    @property
    def priority(self) -> int | None: ...

    @property
    def rearm_s(self) -> float: ...


class TunedSite(Protocol):
    """A site's zones and rules (fence.site.Site; this package imports no fence)."""

    @property
    def zones(self) -> Sequence[Tuned]: ...

    @property
    def rules(self) -> Sequence[Tuned]: ...


@dataclass(frozen=True)
class AlarmSettings:
    """What the incident book needs of the site: per zone and per rule name, its Tuning;
    default_rearm_s for the cameras, the service and names the site does not have."""

    zones: Mapping[str, Tuning] = field(default_factory=dict)
    rules: Mapping[str, Tuning] = field(default_factory=dict)
    default_rearm_s: float = DEFAULT_REARM_S

    @classmethod
    def from_site(cls, site: TunedSite, default_rearm_s: float = DEFAULT_REARM_S) -> AlarmSettings:
        """From anything with `zones` and `rules` whose items have `name`, `priority` and
        `rearm_s` (fence.site.Site; read by attribute so this package imports no fence)."""

        def table(items: Iterable[Tuned]) -> dict[str, Tuning]:
            return {x.name: Tuning(x.priority, x.rearm_s) for x in items}

        return cls(table(site.zones), table(site.rules), default_rearm_s)

    def tuning(self, key: HazardKey) -> Tuning:
        """The settings of a hazard: its zone's, its rule's, or the defaults."""
        where = (
            self.zones
            if key[0] in ("zone", "left_work_area")
            else (self.rules if key[0] == "rule" else None)
        )
        found = where.get(str(key[1])) if where is not None else None
        return found if found is not None else Tuning(None, self.default_rearm_s)

    def priority(self, key: HazardKey, kind: str, type_: str) -> int:
        """The priority of an event of this hazard: the zone's or rule's, else the default."""
        p = self.tuning(key).priority
        return default_priority(kind, type_) if p is None else p
