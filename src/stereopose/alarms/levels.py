"""Which events are alarms, which hazard each belongs to, and which event ends it.

Every event has a level (`level`): alarm, warning or info. Alarms and warnings belong to an
incident; info events belong to none (their `incident` is null in the events contract). The
hazard an event concerns is its key (`hazard_key`):

    ("zone", zone, person)            enter, approach, dwell, exit of a person at a zone
    ("left_work_area", zone, person)  an expected person out of their work area
    ("rule", rule, person)            a behaviour rule's alarm and its end
    ("camera", camera)                camera_down / camera_up
    ("calibration", camera)           calibration_drift / calibration_recovered
    ("service",)                      service_stalled / service_resumed
    ("warning_output", name)          warning_output_down / warning_output_back (a speaker or
                                      a signal on site, onsite.warner; its name in `source`)
    ("silenced", name)                warning_output_silenced / warning_output_unsilenced (an
                                      admin silenced it for a time, onsite.control)
    ("ticket", ticket, step)          a step's deviation (out of order, wrong position,
                                      timeout), cleared when the step is done
    ("ticket", ticket, "supervisor")  supervisor_absent / supervisor_back
    ("ticket", ticket, "lone")        lone_in_room / lone_in_room_end

ticket_completed clears every open incident of its ticket (the key ("ticket", ticket) stands
for all of them).

A camera's picture and its calibration are two hazards: a camera that comes back does not
make its drifted calibration good again, so camera_up must not clear a calibration incident.

The event types are written out here rather than imported (stereopose.behaviour imports this
package for the site file's defaults); tests/alarms check that they agree with the modules
that raise the events. site.eventlog.level gives the same levels and should call this one.
"""

from __future__ import annotations

from typing import Literal

from stereopose.types import Event

__all__ = [
    "ALARM",
    "BEHAVIOUR_ALARMS",
    "BEHAVIOUR_ENDS",
    "INFO",
    "POWER_TYPES",
    "TICKET_ALARMS",
    "WARNING",
    "HazardKey",
    "clears",
    "hazard_key",
    "level",
    "raises",
]

ALARM, WARNING, INFO = "alarm", "warning", "info"
Level = Literal["alarm", "warning", "info"]
HazardKey = tuple[str | int, ...]

# each behaviour alarm and the event that ends it (stereopose.behaviour.rules)
BEHAVIOUR_ENDS = {
    "person_down": "person_up",
    "lone_worker": "lone_worker_end",
    "work_position": "work_position_end",
    "immobile": "immobile_end",
    "overreach": "overreach_end",
}
BEHAVIOUR_ALARMS = frozenset(BEHAVIOUR_ENDS)
# the camera's and the service's own: each condition and the event that ends it
DIAGNOSTIC_ENDS = {
    "camera_down": "camera_up",
    "calibration_drift": "calibration_recovered",
    "service_stalled": "service_resumed",
    "site_invalid": "site_valid",  # the site file (SIGHUP) does not load; loads again
    "warning_output_down": "warning_output_back",  # a beacon's or a speaker's device on site
    "warning_output_silenced": "warning_output_unsilenced",  # by an admin, for a time
}
# a ticket's deviations (stereopose.tickets.monitor); the supervisor's and the lone worker's end
TICKET_ENDS = {"supervisor_absent": "supervisor_back", "lone_in_room": "lone_in_room_end"}
TICKET_STEP_ALARMS = frozenset({"step_out_of_order", "step_wrong_position", "step_timeout"})
TICKET_ALARMS = TICKET_STEP_ALARMS | frozenset(TICKET_ENDS)
# an energized zone's state from its breakers (zones.power_state): unknown (a diagnostic: the
# zone counts as live) until it is known again, live or dead
POWER_TYPES = frozenset({"zone_unknown", "zone_live", "zone_dead"})
_ALARM_TYPES = (
    frozenset(
        {"camera_down", "service_stalled", "zone_unknown", "site_invalid", "warning_output_down"}
    )
    | BEHAVIOUR_ALARMS
    | TICKET_ALARMS
)
_WARNING_TYPES = frozenset(
    {"dwell", "left_work_area", "calibration_drift", "warning_output_silenced"}
)
_ENDS = frozenset(BEHAVIOUR_ENDS.values()) | frozenset(DIAGNOSTIC_ENDS.values())


def level(kind: str, type_: str) -> Level:
    """alarm: entering or approaching an energized zone, a camera down, the service stalled,
    a behaviour alarm (person_down, lone_worker, work_position, immobile, overreach);
    warning: dwell, leaving the work area, calibration drift, entering a restricted zone, a
    warning output silenced by an admin;
    info: the rest (exits, the ends of conditions, entering a work area)."""
    if (kind == "energized" and type_ in ("enter", "approach")) or type_ in _ALARM_TYPES:
        return ALARM
    if type_ in _WARNING_TYPES or (kind == "restricted" and type_ == "enter"):
        return WARNING
    return INFO


def hazard_key(event: Event) -> HazardKey | None:
    """The hazard an event concerns (see the module's table), also for the events that end
    one; None for an event that concerns no hazard (an enter of a work area is no hazard, but
    it ends a left_work_area: see `clears`)."""
    t = event.type
    if event.kind == "ticket":
        return _ticket_key(event)
    if t == "left_work_area":
        return ("left_work_area", event.zone, event.person)
    if t in BEHAVIOUR_ALARMS or (event.rule is not None and t in _ENDS):
        return ("rule", event.rule or "", event.person)
    if t in ("camera_down", "camera_up"):
        return ("camera", event.camera or "")
    if t in ("calibration_drift", "calibration_recovered"):
        return ("calibration", event.camera or "")
    if t in ("service_stalled", "service_resumed"):
        return ("service",)
    if t in ("site_invalid", "site_valid"):
        return ("site",)
    if t in ("warning_output_down", "warning_output_back"):
        return ("warning_output", event.source or "")
    if t in ("warning_output_silenced", "warning_output_unsilenced"):
        return ("silenced", event.source or "")
    if t in POWER_TYPES:
        return ("power", event.zone)
    if t in ("enter", "approach", "dwell", "exit") and event.zone:
        return ("zone", event.zone, event.person)
    return None


def _ticket_key(event: Event) -> HazardKey | None:
    t, ticket = event.type, event.ticket or ""
    if t in TICKET_STEP_ALARMS or t == "step_done":
        return ("ticket", ticket, event.step or "")
    if t in ("supervisor_absent", "supervisor_back"):
        return ("ticket", ticket, "supervisor")
    if t in ("lone_in_room", "lone_in_room_end"):
        return ("ticket", ticket, "lone")
    return None


def raises(event: Event) -> bool:
    """Whether the event activates its hazard's incident (an alarm or a warning)."""
    return level(event.kind, event.type) != INFO


def clears(event: Event) -> list[HazardKey]:
    """The hazards whose condition this event ends: an exit ends its zone's (the person is
    out: an exit is raised only once out for the zone's exit delay), an enter of a zone ends
    an absence from it (left_work_area), `<type>_end` / person_up / camera_up /
    calibration_recovered / service_resumed end theirs."""
    t = event.type
    if event.kind == "ticket":
        if t == "ticket_completed":
            return [("ticket", event.ticket or "")]
        key = _ticket_key(event)
        return [key] if key is not None and t not in TICKET_ALARMS else []
    if t in ("zone_live", "zone_dead"):
        return [("power", event.zone)]
    if t == "exit" and event.zone:
        return [("zone", event.zone, event.person)]
    if t == "enter" and event.zone:
        return [("left_work_area", event.zone, event.person)]
    if t in _ENDS:
        key = hazard_key(event)
        return [] if key is None else [key]
    return []
