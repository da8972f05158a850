"""Priorities: the defaults' order, the site file's values, the settings per zone and rule."""

from __future__ import annotations

from pathlib import Path

import pytest

from stereopose.alarms.priority import (
    CRITICAL,
    DEFAULT_REARM_S,
    HIGH,
    LOW,
    MEDIUM,
    PRIORITY_NAMES,
    AlarmSettings,
    default_priority,
    parse_priority,
)
from stereopose.errors import ConfigError
from stereopose.fence import load_site

# (kind, type) from the most urgent tier to the least: each tier above the next
TIERS = [
    [("energized", "enter"), ("behaviour", "person_down")],
    [("energized", "approach"), ("behaviour", "lone_worker")],
    [
        ("behaviour", "work_position"),
        ("behaviour", "immobile"),
        ("behaviour", "overreach"),
        ("restricted", "enter"),
        ("work_area", "dwell"),
        ("work_area", "left_work_area"),
    ],
    [("camera", "camera_down"), ("camera", "calibration_drift"), ("service", "service_stalled")],
]


def test_four_levels_one_the_most_urgent() -> None:
    assert PRIORITY_NAMES == {1: "critical", 2: "high", 3: "medium", 4: "low"}
    assert CRITICAL < HIGH < MEDIUM < LOW


@pytest.mark.parametrize("tier", range(len(TIERS)))
def test_default_priorities_in_the_order_of_danger(tier: int) -> None:
    for kind, type_ in TIERS[tier]:
        assert default_priority(kind, type_) == tier + 1, (kind, type_)


@pytest.mark.parametrize(
    ("value", "expected"),
    [(1, 1), (4, 4), ("critical", 1), ("High", 2), (" medium ", 3), ("low", 4)],
)
def test_priority_values(value, expected: int) -> None:
    assert parse_priority(value, "zone 'a'") == expected


@pytest.mark.parametrize("value", [0, 5, -1, 2.0, 1.5, True, None, "", "urgent", [1], 2**70])
def test_bad_priority_values_name_where_and_what(value) -> None:
    with pytest.raises(ConfigError) as e:
        parse_priority(value, "zone 'a'")
    assert str(e.value).startswith("zone 'a': priority: expected an integer in [1, 4]")
    assert repr(value) in str(e.value)


SITE = """
[[zones]]
name = "panel"
kind = "energized"
polygon = [[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]]
z = [0.0, 2.5]
priority = "high"
rearm_s = 5
[[zones]]
name = "door"
kind = "restricted"
polygon = [[3.0, 0.0], [4.0, 0.0], [4.0, 1.0], [3.0, 1.0]]
z = [0.0, 2.5]
[[rules]]
name = "man_down"
type = "person_down"
priority = 2
rearm_s = 60
"""


def test_settings_from_the_site_file(tmp_path: Path) -> None:
    path = tmp_path / "site.toml"
    path.write_text(SITE, encoding="utf-8")
    s = AlarmSettings.from_site(load_site(path), default_rearm_s=20.0)
    # the zone's priority replaces the defaults of all its events
    assert s.priority(("zone", "panel", 1), "energized", "enter") == HIGH
    assert s.priority(("zone", "panel", 1), "energized", "approach") == HIGH
    assert s.tuning(("zone", "panel", 1)).rearm_s == 5.0
    assert s.priority(("zone", "door", 1), "restricted", "enter") == MEDIUM
    assert s.tuning(("zone", "door", 1)).rearm_s == DEFAULT_REARM_S  # the zone's own default
    assert s.priority(("rule", "man_down", 3), "behaviour", "person_down") == HIGH
    assert s.tuning(("rule", "man_down", 3)).rearm_s == 60.0
    # cameras, the service and names the site lacks: the defaults
    assert s.priority(("camera", "c1"), "camera", "camera_down") == LOW
    assert s.tuning(("camera", "c1")).rearm_s == 20.0
    assert s.tuning(("zone", "gone", 1)).rearm_s == 20.0
