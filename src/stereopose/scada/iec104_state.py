"""What the outstation's points are computed from: the zones' occupants, the cameras up, the
service's state, the people count and the open incidents; and each monitoring point's value
and quality now (`values`). Folded by the outstation's thread; the open incidents are also read
by the commands' thread (under `lock`)."""

from __future__ import annotations

import threading
from dataclasses import dataclass, field
from typing import Any

from stereopose.scada.points import TICKET_SLOTS, Point, PointsTable

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
    records: dict[int, Any] = field(default_factory=dict)  # open incidents by id
    # the ticket in each slot (1 .. TICKET_SLOTS; None: free) and each one's steps done
    slots: list[str | None] = field(default_factory=lambda: [None] * TICKET_SLOTS)
    power: dict[str, str] = field(default_factory=dict)  # zone -> live, dead, unknown
    steps_done: dict[str, int] = field(default_factory=dict)
    lock: threading.Lock = field(default_factory=threading.Lock)

    def event(self, e: Any) -> None:
        """A zone, camera or service event folded in."""
        if e.kind == "camera" and e.camera in self.camera_up:
            if e.type == "camera_down":
                self.camera_up[e.camera] = False
            elif e.type == "camera_up":
                self.camera_up[e.camera] = True
        elif e.kind == "ticket":
            self._ticket(e)
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

    def _ticket(self, e: Any) -> None:
        """A ticket's event: started, it takes the lowest free slot; ended, frees it."""
        tid = e.ticket
        if e.type == "ticket_started" and tid not in self.slots and None in self.slots:
            self.slots[self.slots.index(None)] = tid
            self.steps_done[tid] = 0
        elif e.type == "step_done" and tid in self.steps_done:
            self.steps_done[tid] += 1
        elif e.type == "ticket_completed" and tid in self.slots:
            self.slots[self.slots.index(tid)] = None
            self.steps_done.pop(tid, None)

    def record(self, r: Any) -> None:
        """An incident's record (alarms.IncidentRecord) kept while open, forgotten closed."""
        with self.lock:
            if r.state == "closed":
                self.records.pop(r.id, None)
            else:
                self.records[r.id] = r

    def open_records(self) -> list[Any]:
        with self.lock:
            return list(self.records.values())

    def values(self, table: PointsTable) -> dict[int, tuple[Any, bool]]:
        """ioa -> (value, invalid) of every monitoring point of `table` now."""
        records = self.open_records()
        zone_alarm = {r.zone for r in records if r.active and r.zone is not None}
        rule_alarm = {r.rule for r in records if r.active and r.rule is not None}
        unacked = sum(r.state in UNACKED for r in records)
        # a ticket's deviation stays on until its incident is over and acknowledged (closed):
        # a step's incident clears as soon as the step is done, often in the same step
        deviating = {r.key[1] for r in records if r.key and r.key[0] == "ticket"}
        now = {
            "service_running": self.running and not self.stalled,
            "service_degraded": self.degraded,
            "people": self.people,
            "unacknowledged": unacked,
        }
        out = {}
        for p in table.monitored:
            if p.kind in now:
                value = now[p.kind]
            elif p.kind == "camera_up":
                value = self.camera_up.get(p.name, True)
            elif p.kind == "zone_occupied":
                value = bool(self.inside.get(p.name))
            elif p.kind == "zone_live":
                value = self.power.get(p.name, "unknown") != "dead"
            elif p.kind.startswith("ticket_"):
                tid = self.slots[int(p.name) - 1]
                if p.kind == "ticket_steps":
                    value = self.steps_done.get(tid, 0) if tid is not None else 0
                else:
                    value = tid is not None and (p.kind == "ticket_active" or tid in deviating)
            else:  # zone_alarm, rule_alarm
                value = p.name in (zone_alarm if p.kind == "zone_alarm" else rule_alarm)
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
            return self.stalled or self.power.get(p.name, "unknown") == "unknown"
        return self.stalled or any(not self.camera_up.get(c, True) for c in p.cameras)
