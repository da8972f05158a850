"""What the outstation's points are computed from: the zones' occupants, the cameras up, the
service's state, the people count and the open incidents; and each monitoring point's value
and quality now (`values`). Folded by the outstation's thread; the open incidents are also read
by the commands' thread (under `lock`)."""

from __future__ import annotations

import threading
from dataclasses import dataclass, field
from typing import Any

from stereopose.alarms import IncidentRecord
from stereopose.scada.points import Point, PointsTable
from stereopose.scada.ticket_slots import TicketSlots, deviating
from stereopose.types import Event

__all__ = ["UNACKED", "PointState"]

UNACKED = ("active", "cleared")  # an incident's states that are not yet acknowledged


@dataclass
class PointState:
    """See the module. inside: zone -> the people inside; camera_up: camera -> up."""

    inside: dict[str, set[int]]
    camera_up: dict[str, bool]
    stalled: bool = False
    running: bool = True
    degraded: bool = False
    people: int = 0
    records: dict[int, IncidentRecord] = field(default_factory=dict)  # open incidents by id
    tickets: TicketSlots = field(default_factory=TicketSlots)  # the active tickets' slots
    power: dict[str, str] = field(default_factory=dict)  # zone -> live, dead, unknown
    lock: threading.Lock = field(default_factory=threading.Lock)

    def event(self, e: Event) -> None:
        """A zone, camera or service event folded in."""
        if e.kind == "camera" and e.camera in self.camera_up:
            if e.type == "camera_down":
                self.camera_up[e.camera] = False
            elif e.type == "camera_up":
                self.camera_up[e.camera] = True
        elif e.kind == "ticket":
            self.tickets.event(e)
        elif e.type in ("zone_live", "zone_dead", "zone_unknown"):
            self.power[e.zone] = e.type[5:]
        elif e.kind == "service":
            if e.type == "service_stalled":
                self.stalled = True
            elif e.type == "service_resumed":
                self.stalled = False
        elif e.zone in self.inside:
            if e.type == "enter":
                self.inside[e.zone].add(int(e.person))
            elif e.type == "exit":
                self.inside[e.zone].discard(int(e.person))

    def record(self, r: IncidentRecord) -> None:
        """An incident's record (alarms.IncidentRecord) kept while open, forgotten closed."""
        with self.lock:
            if r.state == "closed":
                self.records.pop(r.id, None)
            else:
                self.records[r.id] = r

    def open_records(self) -> list[IncidentRecord]:
        with self.lock:
            return list(self.records.values())

    def values(self, table: PointsTable) -> dict[int, tuple[Any, bool]]:
        """ioa -> (value, invalid) of every monitoring point of `table` now."""
        records = self.open_records()
        zone_alarm = {r.zone for r in records if r.active and r.zone is not None}
        rule_alarm = {r.rule for r in records if r.active and r.rule is not None}
        unacked = sum(r.state in UNACKED for r in records)
        slots = self.tickets.rows(deviating(records))  # (the closed ones are not held)
        now = {
            "service_running": self.running and not self.stalled,
            "service_degraded": self.degraded,
            "people": self.people,
            "unacknowledged": unacked,
        }
        out = {}
        for p in table.monitored:
            name = p.name or ""  # the camera, zone or slot a point is of
            if p.kind in now:
                value = now[p.kind]
            elif p.kind == "camera_up":
                value = self.camera_up.get(name, True)
            elif p.kind == "zone_occupied":
                value = bool(self.inside.get(name))
            elif p.kind == "zone_live":
                value = self.power.get(name, "unknown") != "dead"
            elif p.kind.startswith("ticket_"):
                row = slots[int(name) - 1]
                value = {
                    "ticket_steps": row.steps_done,
                    "ticket_active": row.active,
                    "ticket_deviation": row.deviation,
                }[p.kind]
            else:  # zone_alarm, rule_alarm
                value = name in (zone_alarm if p.kind == "zone_alarm" else rule_alarm)
            out[p.ioa] = (value, self.invalid(p))
        return out

    def invalid(self, p: Point) -> bool:
        """Whether a point's quality is invalid: what it watches no camera sees, or a camera
        that sees it is down, or the service is stalled."""
        if p.unseen:
            return True
        if p.kind in ("service_running", "service_degraded", "unacknowledged"):
            return False
        if p.kind.startswith("ticket_"):
            return self.stalled
        if p.kind == "zone_live":
            return self.stalled or self.power.get(p.name or "", "unknown") == "unknown"
        return self.stalled or any(not self.camera_up.get(c, True) for c in p.cameras)
