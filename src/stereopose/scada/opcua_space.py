"""The site in an OPC UA address space, and each incident as an Alarms and Conditions alarm.

Namespace `urn:stereopose:<site>`; every node id is a string that stays the same across
restarts (a SCADA configuration refers to them), `<site>` standing for [opcua] site:

    Objects/<site>                       s=site
        Running          Boolean         s=site/Running            the frame loop steps
        Status           String          s=site/Status             ok | degraded | down
        People           UInt32          s=site/People             people tracked now
        ActiveIncidents  UInt32          s=site/ActiveIncidents    incidents active
        UnacknowledgedIncidents UInt32   s=site/UnacknowledgedIncidents
        Zones/<zone>                     s=zone/<zone>
            Kind String, Occupied Boolean, Occupants UInt32, Alarm Boolean  s=zone/<zone>/<name>
            Power String (a zone with a state source: live, dead, unknown uncertain)
        Cameras/<camera>                 s=camera/<camera>
            Up Boolean                   s=camera/<camera>/Up
        Incidents/Incident <id>          s=incident/<id>   one per open incident: its condition
        Tickets/Slot<n>                  s=ticket/<n>      n = 1 .. 8, as IEC 104's ticket slots
            Ticket String (its id, "" free), Active Boolean, Deviation Boolean (an incident of
            it not closed), StepsDone UInt32                    s=ticket/<n>/<name>

A zone's values are Uncertain_LastUsableValue while a camera that sees it is down or the
service is stalled, and always for a zone no camera sees (scada.points.cameras_seeing).

Each incident is a condition of type OffNormalAlarmType whose events come from the Server
object (where A&C clients subscribe), with SourceNode its zone, camera or the site object;
Severity from the priority (SEVERITY); ActiveState (active or acknowledged), AckedState
(acknowledged or closed), Retain (not closed: a closed incident's last event has Retain false
and its node goes), ClientUserId the operator who acknowledged, Message naming the zone,
person, rule or camera. ConditionRefresh (asyncua's) replays the retained ones. The state of a
condition is carried by its events: its node has no child variables (asyncua would make 59 per
alarm instance), so that thousands of open incidents stay cheap.
"""

# asyncua makes its event types' fields at run time (OffNormalAlarm's EventId, Message, ...)
# and annotates numbers, strings and times as its own Int32, UInt32, String and DateTime,
# taking plain values for them: these two checks are off in this module, asyncua's address
# space, alone.
# pyright: reportAttributeAccessIssue=false, reportArgumentType=false

from __future__ import annotations

import datetime
import time
import uuid
from collections import deque
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from asyncua import ua
from asyncua.common import event_objects
from asyncua.common.node import Node
from asyncua.server.server import Server
from asyncua.ua.object_ids import ObjectIds
from asyncua.ua.status_codes import StatusCodes

from stereopose.alarms.incident import ACKNOWLEDGED, ACTIVE, CLEARED, CLOSED, IncidentRecord
from stereopose.alarms.priority import PRIORITY_NAMES
from stereopose.scada.ticket_slots import SlotRow, TicketSlots, deviating
from stereopose.tickets.ticket import TICKET_SLOTS

if TYPE_CHECKING:
    from asyncua.common.event_objects import OffNormalAlarm

    from stereopose.fence import Site
    from stereopose.types import Rig

__all__ = [
    "SEVERITY",
    "CameraNode",
    "Condition",
    "SiteSpace",
    "ZoneNode",
    "incident_message",
    "site_zones",
]

# priority (1 critical ... 4 low) -> OPC UA severity (1-1000), one per band of OPC 10000-9
# 5.3 (801-1000 high, 601-800 medium high, 401-600 medium, 1-200 low)
SEVERITY = {1: 900, 2: 700, 3: 500, 4: 200}
EVENT_IDS_KEPT = 16  # a condition's latest events an Acknowledge may name
_VERBS = {"enter": "entered", "approach": "approaching", "dwell": "dwelling in"}
_SAFETY, _SYSTEM = ObjectIds.SafetyConditionClassType, ObjectIds.SystemConditionClassType
_SLOT_VARIABLES = (
    ("Ticket", "", ua.VariantType.String),
    ("Active", False, ua.VariantType.Boolean),
    ("Deviation", False, ua.VariantType.Boolean),
    ("StepsDone", 0, ua.VariantType.UInt32),
)


@dataclass(frozen=True)
class ZoneNode:
    """A zone as the address space shows it: its name, kind and the cameras that see it."""

    name: str
    kind: str
    cameras: tuple[str, ...]
    powered: bool = False  # a state source (zones.power): its Power variable


@dataclass(frozen=True)
class CameraNode:
    name: str


@dataclass
class Condition:
    """An open incident's condition: its node, its latest record and the ids of its latest
    events (an Acknowledge names one of them)."""

    node: ua.NodeId
    record: IncidentRecord
    severity: int
    event_ids: deque[bytes] = field(default_factory=lambda: deque(maxlen=EVENT_IDS_KEPT))

    @property
    def acked(self) -> bool:
        return self.record.state in (ACKNOWLEDGED, CLOSED)


def incident_message(rec: IncidentRecord) -> str:
    """What the incident is, for the alarm's Message: its priority and what it names."""
    kind, p = rec.key[0], rec.person
    what = rec.last_type
    if kind == "zone":
        text = f"person {p} {_VERBS.get(what, what)} zone {rec.zone}"
    elif kind == "left_work_area":
        text = f"person {p} left work area {rec.zone}"
    elif kind == "rule":
        text = f"{what.replace('_', ' ')} (rule {rec.rule}): person {p}"
    elif kind == "camera":
        text = f"camera {rec.camera} down"
    elif kind == "calibration":
        text = f"camera {rec.camera}: calibration drifting"
    elif kind == "service":
        text = "service stalled"
    else:
        text = f"{what} ({', '.join(map(str, rec.key))})"
    if rec.occurrences > 1:
        text += f", {rec.occurrences} times"
    return f"{PRIORITY_NAMES.get(rec.priority, rec.priority)}: {text}"


def _utc(wall: float | None) -> datetime.datetime:
    return datetime.datetime.fromtimestamp(time.time() if wall is None else wall, datetime.UTC)


def _text(s: str) -> ua.LocalizedText:
    return ua.LocalizedText(s, "en")


class SiteSpace:
    """The site's nodes in `server` (see the module), updated from the server's event loop
    only. zones, cameras: what the address space shows; site: the site object's name."""

    def __init__(
        self, server: Server, site: str, zones: Sequence[ZoneNode], cameras: Sequence[CameraNode]
    ) -> None:
        self.server, self.site = server, site
        self.zones = {z.name: z for z in zones}
        self.cameras = [c.name for c in cameras]
        self.idx = 0
        self.conditions: dict[int, Condition] = {}
        self.by_node: dict[ua.NodeId, int] = {}
        self._camera_up = dict.fromkeys(self.cameras, True)
        self._stalled = False
        self._zone_values: dict[str, tuple[int, bool]] = {}
        # per zone, the wall times of its occupancy's and its alarm's last change
        self._zone_t: dict[str, float | None] = {}
        self._alarm_t: dict[str, float | None] = {}
        self._slots: dict[int, SlotRow] = {}  # each ticket slot as last written

    def nid(self, path: str) -> ua.NodeId:
        return ua.NodeId(path, self.idx)

    def qn(self, name: str) -> ua.QualifiedName:
        return ua.QualifiedName(name, self.idx)

    async def build(self) -> None:
        s = self.server
        self.idx = await s.register_namespace(f"urn:stereopose:{self.site}")
        site = await s.nodes.objects.add_object(self.nid("site"), self.qn(self.site))
        for name, value, vt in (
            ("Running", True, ua.VariantType.Boolean),
            ("Status", "ok", ua.VariantType.String),
            ("People", 0, ua.VariantType.UInt32),
            ("ActiveIncidents", 0, ua.VariantType.UInt32),
            ("UnacknowledgedIncidents", 0, ua.VariantType.UInt32),
        ):
            await site.add_variable(
                self.nid(f"site/{name}"), ua.QualifiedName(name, self.idx), value, vt
            )
        zones = await site.add_folder(self.nid("site/Zones"), ua.QualifiedName("Zones", self.idx))
        for z in self.zones.values():
            obj = await zones.add_object(
                self.nid(f"zone/{z.name}"), ua.QualifiedName(z.name, self.idx)
            )
            await obj.add_property(
                self.nid(f"zone/{z.name}/Kind"),
                ua.QualifiedName("Kind", self.idx),
                z.kind,
                ua.VariantType.String,
            )
            for name, value, vt in (
                ("Occupied", False, ua.VariantType.Boolean),
                ("Occupants", 0, ua.VariantType.UInt32),
                ("Alarm", False, ua.VariantType.Boolean),
            ):
                await obj.add_variable(
                    self.nid(f"zone/{z.name}/{name}"), ua.QualifiedName(name, self.idx), value, vt
                )
            if z.powered:  # live, dead or unknown (uncertain), from its breakers
                await obj.add_variable(
                    self.nid(f"zone/{z.name}/Power"),
                    ua.QualifiedName("Power", self.idx),
                    "unknown",
                    ua.VariantType.String,
                )
            self._zone_values[z.name] = (0, False)
            self._zone_t[z.name] = self._alarm_t[z.name] = None
        cams = await site.add_folder(self.nid("site/Cameras"), self.qn("Cameras"))
        for c in self.cameras:
            obj = await cams.add_object(self.nid(f"camera/{c}"), ua.QualifiedName(c, self.idx))
            await obj.add_variable(
                self.nid(f"camera/{c}/Up"),
                ua.QualifiedName("Up", self.idx),
                True,
                ua.VariantType.Boolean,
            )
        await site.add_folder(self.nid("site/Incidents"), ua.QualifiedName("Incidents", self.idx))
        await self._build_tickets(site)
        for z in self.zones.values():  # a zone no camera sees is uncertain from the start
            await self._write_zone(z.name)
            await self.set_power(z.name, "unknown", None)  # uncertain until its state is known

    async def _build_tickets(self, site: Node) -> None:
        """Tickets/Slot<n> (n = 1 .. TICKET_SLOTS, as IEC 104's ticket points): Ticket (its
        id, "" when free), Active, Deviation (an incident of it not closed), StepsDone."""
        folder = await site.add_folder(self.nid("site/Tickets"), self.qn("Tickets"))
        for k in range(1, TICKET_SLOTS + 1):
            obj = await folder.add_object(self.nid(f"ticket/{k}"), self.qn(f"Slot{k}"))
            for name, value, vt in _SLOT_VARIABLES:
                await obj.add_variable(self.nid(f"ticket/{k}/{name}"), self.qn(name), value, vt)

    async def set_tickets(self, tickets: TicketSlots) -> None:
        """Each slot's ticket, whether it deviates (from the conditions held), its steps done:
        the slots that changed written."""
        open_records = [c.record for c in self.conditions.values()]
        for row in tickets.rows(deviating(open_records)):
            if self._slots.get(row.slot) == row:
                continue
            self._slots[row.slot] = row
            for name, value, vt in (
                ("Ticket", row.ticket or "", ua.VariantType.String),
                ("Active", row.active, ua.VariantType.Boolean),
                ("Deviation", row.deviation, ua.VariantType.Boolean),
                ("StepsDone", row.steps_done, ua.VariantType.UInt32),
            ):
                await self.write(f"ticket/{row.slot}/{name}", value, vt)

    # -- values ---------------------------------------------------------------------------

    async def write(
        self,
        path: str,
        value: object,
        vt: ua.VariantType,
        wall: float | None = None,
        good: bool = True,
    ) -> None:
        status = ua.StatusCode(StatusCodes.Good if good else StatusCodes.UncertainLastUsableValue)
        dv = ua.DataValue(
            ua.Variant(value, vt),
            StatusCode=status,
            SourceTimestamp=_utc(wall),
            ServerTimestamp=_utc(None),
        )
        await self.server.write_attribute_value(self.nid(path), dv)

    async def set_zone(self, zone: str, occupants: int, wall: float | None) -> None:
        if zone not in self.zones:
            return
        self._zone_values[zone] = (occupants, self._zone_values[zone][1])
        self._zone_t[zone] = wall
        await self._write_zone(zone, alarm=False)

    async def _write_zone(self, zone: str, occupancy: bool = True, alarm: bool = True) -> None:
        """The zone's occupancy and/or alarm values, each with the time of its own change and
        the quality its cameras give now."""
        z = self.zones[zone]
        occupants, alarmed = self._zone_values[zone]
        good = (
            bool(z.cameras)
            and not self._stalled
            and all(self._camera_up.get(c, True) for c in z.cameras)
        )
        if occupancy:
            when = self._zone_t[zone]
            await self.write(f"zone/{zone}/Occupants", occupants, ua.VariantType.UInt32, when, good)
            await self.write(
                f"zone/{zone}/Occupied", occupants > 0, ua.VariantType.Boolean, when, good
            )
        if alarm:
            await self.write(
                f"zone/{zone}/Alarm", alarmed, ua.VariantType.Boolean, self._alarm_t[zone], good
            )

    async def set_power(self, zone: str, state: str, wall: float | None) -> None:
        """A zone's state from its breakers (good quality when known)."""
        z = self.zones.get(zone)
        if z is None or not z.powered:
            return
        path = f"zone/{zone}/Power"
        await self.write(path, state, ua.VariantType.String, wall, state != "unknown")

    async def set_camera(self, camera: str, up: bool, wall: float | None) -> None:
        if camera not in self._camera_up:
            return
        self._camera_up[camera] = up
        await self.write(f"camera/{camera}/Up", up, ua.VariantType.Boolean, wall)
        for z in self.zones.values():
            if camera in z.cameras:
                await self._write_zone(z.name)

    async def set_stalled(self, stalled: bool) -> None:
        if stalled != self._stalled:
            self._stalled = stalled
            for z in self.zones:
                await self._write_zone(z)

    # -- conditions -----------------------------------------------------------------------

    async def apply(
        self,
        records: Iterable[tuple[IncidentRecord, float | None, float | None]],
    ) -> None:
        """Each (record, wall time of the change, wall_start) as its condition's event, then
        the counts and the zones' alarms; a record equal to the one held is skipped."""
        touched: dict[str, float | None] = {}
        for rec, wall, wall_start in records:
            held = self.conditions.get(rec.id)
            if held is not None and held.record == rec:
                continue
            if held is None and rec.state == CLOSED:
                continue  # never shown open: nothing for a client to remove
            await self._emit(rec, wall, wall_start)
            if rec.zone is not None:
                touched[rec.zone] = wall
        await self._counts(touched)

    async def drop(self, rec: IncidentRecord, wall: float | None, wall_start: float | None) -> None:
        """The book dropped it (full): its condition's last event, not retained."""
        if rec.id in self.conditions:
            await self._emit(rec, wall, wall_start, retain=False)
            await self._counts({rec.zone: wall} if rec.zone else {})

    async def _counts(self, zones: dict[str, float | None]) -> None:
        """The incident counts, and the alarm of `zones` (zone -> wall time of its change)."""
        recs = [c.record for c in self.conditions.values()]
        active = sum(r.state in (ACTIVE, ACKNOWLEDGED) for r in recs)
        unacked = sum(r.state in (ACTIVE, CLEARED) for r in recs)
        await self.write("site/ActiveIncidents", active, ua.VariantType.UInt32)
        await self.write("site/UnacknowledgedIncidents", unacked, ua.VariantType.UInt32)
        alarmed = {r.zone for r in recs if r.zone is not None and r.active}
        for zone, wall in zones.items():
            if zone in self.zones and self._zone_values[zone][1] != (zone in alarmed):
                self._zone_values[zone] = (self._zone_values[zone][0], zone in alarmed)
                self._alarm_t[zone] = wall
                await self._write_zone(zone, occupancy=False)

    async def _emit(
        self,
        rec: IncidentRecord,
        wall: float | None,
        wall_start: float | None,
        retain: bool | None = None,
    ) -> None:
        cond = self.conditions.get(rec.id)
        if cond is None:
            cond = Condition(await self._add_node(rec.id), rec, SEVERITY.get(rec.priority, 500))
            self.conditions[rec.id] = cond
            self.by_node[cond.node] = rec.id
        last_severity, cond.record = cond.severity, rec
        cond.severity = SEVERITY.get(rec.priority, 500)
        if retain is None:
            retain = rec.state != CLOSED
        ev = self._event(cond, rec, wall, wall_start, last_severity, retain)
        cond.event_ids.append(ev.EventId)
        await self.server.iserver.subscription_service.trigger_event(ev)
        if not retain:
            del self.conditions[rec.id]
            del self.by_node[cond.node]
            await self.server.delete_nodes([self.server.get_node(cond.node)])

    async def _add_node(self, incident_id: int) -> ua.NodeId:
        """The condition's node, of OffNormalAlarmType without its children (see the module)."""
        name = f"Incident {incident_id}"
        item = ua.AddNodesItem()
        item.RequestedNewNodeId = self.nid(f"incident/{incident_id}")
        item.BrowseName = ua.QualifiedName(name, self.idx)
        item.NodeClass = ua.NodeClass.Object
        item.ParentNodeId = self.nid("site/Incidents")
        item.ReferenceTypeId = ua.NodeId(ObjectIds.HasComponent)
        item.TypeDefinition = ua.NodeId(ObjectIds.OffNormalAlarmType)
        attrs = ua.ObjectAttributes()
        attrs.DisplayName = _text(name)
        item.NodeAttributes = attrs
        result = (await self.server.iserver.isession.add_nodes([item]))[0]
        if result.StatusCode.is_bad() and result.StatusCode.value != StatusCodes.BadNodeIdExists:
            result.StatusCode.check()
        return item.RequestedNewNodeId

    def _source(self, rec: IncidentRecord) -> tuple[ua.NodeId, str, ua.NodeId | None]:
        """(SourceNode, SourceName, InputNode) of an incident's events."""
        if rec.zone is not None and rec.zone in self.zones:
            return (self.nid(f"zone/{rec.zone}"), rec.zone, self.nid(f"zone/{rec.zone}/Occupied"))
        if rec.camera is not None and rec.camera in self._camera_up:
            return self.nid(f"camera/{rec.camera}"), rec.camera, self.nid(f"camera/{rec.camera}/Up")
        return self.nid("site"), self.site, self.nid("site/Running")

    def _event(
        self,
        cond: Condition,
        rec: IncidentRecord,
        wall: float | None,
        wall_start: float | None,
        last_severity: int,
        retain: bool,
    ) -> OffNormalAlarm:
        def at(t: float | None) -> datetime.datetime | None:
            return None if t is None or wall_start is None else _utc(wall_start + t)

        source, source_name, input_node = self._source(rec)
        ev = event_objects.OffNormalAlarm(
            sourcenode=source, message=incident_message(rec), severity=cond.severity
        )
        ev.add_property("NodeId", cond.node, ua.VariantType.NodeId)  # the ConditionId
        ev.emitting_node = ua.NodeId(ObjectIds.Server)
        ev.Message = _text(incident_message(rec))
        now = _utc(None)
        ev.EventId = uuid.uuid4().bytes
        ev.Time, ev.ReceiveTime = _utc(wall), now
        ev.LocalTime = ua.TimeZoneDataType(Offset=time.localtime().tm_gmtoff // 60)
        ev.SourceName, ev.InputNode = source_name, input_node
        safety = rec.key[0] in ("zone", "left_work_area", "rule")
        ev.ConditionClassId = ua.NodeId(_SAFETY if safety else _SYSTEM)
        ev.ConditionClassName = _text("Safety" if safety else "System")
        ev.ConditionName = f"Incident {rec.id}"
        ev.BranchId = ua.NodeId()
        ev.Retain = retain
        ev.Quality = ua.StatusCode(StatusCodes.Good)
        ev.LastSeverity = last_severity
        ev.Comment = _text("")
        ev.ClientUserId = rec.acked_by or ""
        setattr(ev, "EnabledState/Id", True)
        ev.EnabledState = _text("Enabled")
        active, acked = rec.active, cond.acked
        setattr(ev, "ActiveState/Id", active)
        ev.ActiveState = _text("Active" if active else "Inactive")
        # the UtcTime properties: as DateTime (asyncua types them by a NodeId it cannot encode)
        ev.add_property(
            "ActiveState/TransitionTime",
            at(rec.active_since if active else rec.cleared_at),
            ua.VariantType.DateTime,
        )
        setattr(ev, "AckedState/Id", acked)
        ev.AckedState = _text("Acknowledged" if acked else "Unacknowledged")
        ev.add_property("AckedState/TransitionTime", at(rec.acked_at), ua.VariantType.DateTime)
        ev.SuppressedOrShelved = rec.shelved
        return ev


def site_zones(site: Site | None, rig: Rig) -> list[ZoneNode]:
    """The site's zones (fence.Site, or None: none) with the cameras of `rig` that see each."""
    from stereopose.scada.points import cameras_seeing

    if site is None:
        return []
    return [
        ZoneNode(z.name, z.kind, cameras_seeing(z, rig), z.power is not None) for z in site.zones
    ]
