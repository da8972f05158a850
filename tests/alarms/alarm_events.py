"""Events for the alarms tests: zone, behaviour, camera and service events at chosen times."""

from __future__ import annotations

from stereopose.types import Event


def zone(
    t: float, type_: str, person: int = 1, zone_: str = "panel", kind: str = "energized", **kw
) -> Event:
    """A zone event (enter, exit, approach, dwell, left_work_area) at t."""
    return Event(
        t=t, frame=int(t * 25), person=person, zone=zone_, kind=kind, type=type_, onset_t=t, **kw
    )


def rule(t: float, type_: str, person: int = 1, name: str = "man_down") -> Event:
    """A behaviour event of rule `name` (person_down, person_up, lone_worker, ...) at t."""
    return Event(
        t=t,
        frame=int(t * 25),
        person=person,
        zone="",
        kind="behaviour",
        type=type_,
        onset_t=t,
        rule=name,
    )


def camera(t: float, type_: str, name: str = "cam1") -> Event:
    """camera_down / camera_up / calibration_drift / calibration_recovered of camera `name`."""
    return Event(
        t=t,
        frame=int(t * 25),
        person=-1,
        zone="",
        kind="camera",
        type=type_,
        onset_t=t,
        camera=name,
    )


def service(t: float, type_: str) -> Event:
    """service_stalled / service_resumed."""
    return Event(t=t, frame=int(t * 25), person=-1, zone="", kind="service", type=type_, onset_t=t)
