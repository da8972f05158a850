"""Alarms: incidents over the zone, behaviour, camera and service events (ISA-18.2 states,
priorities, re-arm, shelving, first-out, alarm rates). Pure: no I/O, no clock of its own.

levels     which events are alarms, the hazard each concerns, which event ends it
priority   the four priorities, their defaults, the site file's `priority` and `rearm_s`
incident   one incident's state machine (active, acknowledged, cleared, closed; shelving)
book       IncidentBook: events in, incidents and their changes out
rates      alarm-rate figures: notifications per 10 minutes and hour, chattering, standing
"""

from stereopose.alarms.book import Change, IncidentBook, UnknownIncidentError, Update
from stereopose.alarms.incident import (
    ACKNOWLEDGED,
    ACTIVE,
    CLEARED,
    CLOSED,
    MAX_SHELVE_S,
    STATES,
    IncidentError,
    IncidentRecord,
)
from stereopose.alarms.levels import clears, hazard_key, level, raises
from stereopose.alarms.priority import (
    DEFAULT_REARM_S,
    PRIORITY_NAMES,
    AlarmSettings,
    Tuning,
    default_priority,
)
from stereopose.alarms.rates import AlarmRates, RateFigures

__all__ = [
    "ACKNOWLEDGED",
    "ACTIVE",
    "CLEARED",
    "CLOSED",
    "DEFAULT_REARM_S",
    "MAX_SHELVE_S",
    "PRIORITY_NAMES",
    "STATES",
    "AlarmRates",
    "AlarmSettings",
    "Change",
    "IncidentBook",
    "IncidentError",
    "IncidentRecord",
    "RateFigures",
    "Tuning",
    "UnknownIncidentError",
    "Update",
    "clears",
    "default_priority",
    "hazard_key",
    "level",
    "raises",
]
