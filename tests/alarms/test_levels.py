"""Which events are alarms, the hazard each concerns and the event that ends it; the tables
agree with the modules that raise the events and with the event log's levels."""

from __future__ import annotations

import pytest
from alarm_events import camera, rule, service, zone

from stereopose.alarms.levels import BEHAVIOUR_ALARMS, BEHAVIOUR_ENDS, clears, hazard_key, level
from stereopose.behaviour.definitions import ALARM_TYPES
from stereopose.site import eventlog
from stereopose.site.restart import ALARM_ENDS

KINDS = ("energized", "restricted", "work_area", "behaviour", "camera", "service")
TYPES = (
    "enter",
    "exit",
    "approach",
    "dwell",
    "left_work_area",
    "camera_down",
    "camera_up",
    "calibration_drift",
    "calibration_recovered",
    "service_stalled",
    "service_resumed",
    *BEHAVIOUR_ENDS,
    *BEHAVIOUR_ENDS.values(),
)


def test_the_tables_agree_with_the_modules_that_raise_the_events() -> None:
    assert BEHAVIOUR_ALARMS == ALARM_TYPES
    assert BEHAVIOUR_ENDS == ALARM_ENDS


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("type_", TYPES)
def test_levels_are_the_event_logs(kind: str, type_: str) -> None:
    assert level(kind, type_) == eventlog.level(kind, type_)


@pytest.mark.parametrize(
    ("event", "key", "ends"),
    [
        (zone(0, "enter"), ("zone", "panel", 1), [("left_work_area", "panel", 1)]),
        (zone(0, "approach", person=4), ("zone", "panel", 4), []),
        (zone(0, "dwell", kind="work_area"), ("zone", "panel", 1), []),
        (zone(0, "exit"), ("zone", "panel", 1), [("zone", "panel", 1)]),
        (zone(0, "exit", lost=True), ("zone", "panel", 1), [("zone", "panel", 1)]),
        (zone(0, "left_work_area", kind="work_area"), ("left_work_area", "panel", 1), []),
        (rule(0, "person_down", 2), ("rule", "man_down", 2), []),
        (rule(0, "person_up", 2), ("rule", "man_down", 2), [("rule", "man_down", 2)]),
        (rule(0, "lone_worker_end", 2, "two"), ("rule", "two", 2), [("rule", "two", 2)]),
        (camera(0, "camera_down"), ("camera", "cam1"), []),
        (camera(0, "camera_up"), ("camera", "cam1"), [("camera", "cam1")]),
        (camera(0, "calibration_drift"), ("calibration", "cam1"), []),
        (camera(0, "calibration_recovered"), ("calibration", "cam1"), [("calibration", "cam1")]),
        (service(0, "service_stalled"), ("service",), []),
        (service(0, "service_resumed"), ("service",), [("service",)]),
    ],
)
def test_each_event_its_hazard_and_what_it_ends(event, key, ends) -> None:
    assert hazard_key(event) == key
    assert clears(event) == ends
