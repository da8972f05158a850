"""The IEC 60870-5-104 points of a site: one table, printed for the SCADA engineer and served.

    table = points_table(site, rig, commands=False)
    table.csv()                  # `stereopose points CONFIG.toml`: ioa,type,meaning,source
    table.get("zone_occupied", "overhead_busbar").ioa

The information object addresses (IOA) come in blocks, so that an engineer reads a point's
kind from its address and a zone's points stay together (n counts from 1 in the order of the
site file, or of the calibration's cameras as the configuration names them):

    1                 service running        M_SP_TB_1  on while the frame loop steps
    2                 service degraded       M_SP_TB_1  the health answer is not ok
    11                people on site         M_ME_TE_1  people tracked in the latest step
    12                unacknowledged         M_ME_TE_1  incidents not acknowledged
    20 + p            acknowledge priority p C_SC_NA_1  (commands on) p = 1 critical ... 4 low
    1000 + n          camera n up            M_SP_TB_1
    10000 + 10 n + 1  zone n occupied        M_SP_TB_1  someone inside (its enter/exit events)
    10000 + 10 n + 2  zone n alarm active    M_SP_TB_1  an incident of the zone active
    10000 + 10 n + 3  zone n live            M_SP_TB_1  (a zone with a state source) on: live,
                                                        off: dead; invalid while unknown
    10000 + 10 n + 9  acknowledge zone n     C_SC_NA_1  (commands on)
    30000 + 10 n + 2  rule n alarm active    M_SP_TB_1  an incident of the behaviour rule active
    40000 + 10 s + 1  ticket slot s active   M_SP_TB_1  s = 1 .. 8 (below)
    40000 + 10 s + 2  ticket slot s deviation M_SP_TB_1 an incident of that ticket not closed
    40000 + 10 s + 3  ticket slot s steps    M_ME_TE_1  its steps done

A ticket (stereopose.tickets) takes the lowest free slot when it starts and frees it when it
ends (its ticket_completed), so the SCADA sees up to TICKET_SLOTS tickets at once; the console
and /api/tickets show each active ticket's slot. The ticket points' quality is invalid only
while the service is stalled.

A point's quality is invalid while one of `cameras` (those that see what it watches: a zone's
cameras, a rule's zones' cameras, every camera for people on site and a rule watching the whole
site) is down, or while the service is stalled (site.health.stall); a zone no camera sees is
invalid always. Which cameras see a zone is computed from the calibration: a camera sees a
zone when a point of the zone's prism (its corners, edge midpoints and centre at the bottom,
middle and top of its height band) projects into its image in front of it, near enough that a
person of 1.7 m there would be 32 pixels tall or more (what a pose detector needs).

Adding a zone, rule or camera at the end of its list keeps every other address; reordering or
removing renumbers those after it, so the table goes to the SCADA engineer again.
"""

from __future__ import annotations

import csv
import io
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, overload

import numpy as np

from stereopose.behaviour.definitions import watched_zones
from stereopose.geometry.camera import distort, normalized_to_pixels, world_to_camera
from stereopose.tickets.ticket import TICKET_SLOTS
from stereopose.types import Camera, Rig

if TYPE_CHECKING:
    from stereopose.fence import Site
    from stereopose.zones.zone import Zone

__all__ = [
    "COMMAND",
    "COUNT",
    "HEADER",
    "SINGLE",
    "TICKET_SLOTS",
    "Point",
    "PointsTable",
    "cameras_seeing",
    "points_table",
]

SINGLE, COUNT, COMMAND = "M_SP_TB_1", "M_ME_TE_1", "C_SC_NA_1"  # the IEC 60870-5-101/104 types
HEADER = ("ioa", "type", "meaning", "source")
PRIORITIES = {1: "critical", 2: "high", 3: "medium", 4: "low"}  # alarms.priority's names

SERVICE_RUNNING, SERVICE_DEGRADED, PEOPLE, UNACKNOWLEDGED = 1, 2, 11, 12
PRIORITY_BASE, CAMERA_BASE, ZONE_BASE, RULE_BASE = 20, 1000, 10_000, 30_000
TICKET_BASE = 40_000
TICKET_ACTIVE, TICKET_DEVIATION, TICKET_STEPS = 1, 2, 3
ZONE_OCCUPIED, ZONE_ALARM, ZONE_LIVE, ZONE_ACK, RULE_ALARM = 1, 2, 3, 9, 2
MAX_CAMERAS = 8999  # camera addresses end below the zones' block
PERSON_M, MIN_PERSON_PX = 1.7, 32.0  # a person this tall is seen when this many pixels tall
_MAX_COORD = 3.0  # |x|, |y| normalised: beyond this a lens model folds back (about 72 degrees)


@dataclass(frozen=True)
class Point:
    """One point: ioa (information object address), type (M_SP_TB_1 single point with a
    CP56Time2a time tag, M_ME_TE_1 scaled value with one, C_SC_NA_1 single command), meaning
    and source (the table's text), kind (what the outstation feeds it from: service_running,
    service_degraded, people, unacknowledged, camera_up, zone_occupied, zone_alarm, rule_alarm,
    ack_zone, ack_priority), name (the zone, rule or camera; the priority's number for
    ack_priority; None for the service's points) and cameras (whose being down makes the point
    invalid; `unseen`: no camera sees what it watches, invalid always)."""

    ioa: int
    type: str
    meaning: str
    source: str
    kind: str
    name: str | None = None
    cameras: tuple[str, ...] = ()
    unseen: bool = False

    @property
    def command(self) -> bool:
        return self.type == COMMAND


class PointsTable(Sequence[Point]):
    """The points in address order; `get(kind, name)` finds one (KeyError when absent)."""

    def __init__(self, points: Sequence[Point]) -> None:
        self.points = tuple(sorted(points, key=lambda p: p.ioa))
        ioas = [p.ioa for p in self.points]
        if len(set(ioas)) != len(ioas):
            raise ValueError("two points share an information object address")
        self._by_key = {(p.kind, p.name): p for p in self.points}

    def __len__(self) -> int:
        return len(self.points)

    @overload
    def __getitem__(self, k: int) -> Point: ...
    @overload
    def __getitem__(self, k: slice) -> Sequence[Point]: ...
    def __getitem__(self, k: int | slice) -> Point | Sequence[Point]:
        return self.points[k]

    def __iter__(self) -> Iterator[Point]:
        return iter(self.points)

    def get(self, kind: str, name: str | None = None) -> Point:
        return self._by_key[(kind, name)]

    def find(self, kind: str, name: str | None = None) -> Point | None:
        return self._by_key.get((kind, name))

    @property
    def monitored(self) -> tuple[Point, ...]:
        """The monitoring points (what a general interrogation returns)."""
        return tuple(p for p in self.points if not p.command)

    def rows(self) -> list[tuple[str, str, str, str]]:
        return [(str(p.ioa), p.type, p.meaning, p.source) for p in self.points]

    def csv(self) -> str:
        """The table as CSV with the header ioa,type,meaning,source (RFC 4180 quoting)."""
        buf = io.StringIO()
        w = csv.writer(buf, lineterminator="\n")
        w.writerow(HEADER)
        w.writerows(self.rows())
        return buf.getvalue()


def _sample(polygon: np.ndarray, z: tuple[float, float]) -> np.ndarray:
    """(S, 3) points of a zone's prism: corners, edge midpoints and centre at three heights."""
    poly = np.asarray(polygon, dtype=np.float64)
    floor = np.concatenate([poly, (poly + np.roll(poly, -1, axis=0)) / 2, poly.mean(0)[None]])
    heights = (z[0], (z[0] + z[1]) / 2, z[1])
    return np.concatenate([np.column_stack([floor, np.full(len(floor), h)]) for h in heights])


def _in_view(points_world: np.ndarray, camera: Camera) -> bool:
    """Whether any of (S, 3) world points lands in the camera's image, in front of it."""
    cam = world_to_camera(points_world, camera)
    # in front, and near enough that a person standing there is tall enough to be detected
    front = (cam[:, 2] > 1e-3) & (cam[:, 2] <= camera.matrix[1, 1] * PERSON_M / MIN_PERSON_PX)
    if not front.any():
        return False
    xy = cam[front, :2] / cam[front, 2:3]
    xy = xy[np.all(np.abs(xy) <= _MAX_COORD, axis=1)]
    if not len(xy):
        return False
    px = normalized_to_pixels(distort(xy, camera.distortions), camera.matrix)
    w, h = camera.size
    return bool(np.any((px[:, 0] >= 0) & (px[:, 0] <= w) & (px[:, 1] >= 0) & (px[:, 1] <= h)))


def cameras_seeing(zone: Zone, rig: Rig) -> tuple[str, ...]:
    """The names of the rig's cameras that see the zone (fence.Zone: polygon (V, 2) metres,
    z (bottom, top) metres), in the rig's order."""
    pts = _sample(zone.polygon, zone.z)
    return tuple(c.name for c in rig if _in_view(pts, c))


def _quality(cameras: Sequence[str], unseen: bool) -> str:
    if unseen:
        return "invalid always: no camera sees it"
    which = f"camera {cameras[0]} is" if len(cameras) == 1 else f"any of {', '.join(cameras)} is"
    return f"invalid while {which} down or the service stalled"


def points_table(site: Site | None, rig: Rig, *, commands: bool = False) -> PointsTable:
    """The points of a service with `site` (fence.Site, or None: no zone or rule) and `rig`;
    commands: the acknowledge commands per zone and priority too."""
    if len(rig) > MAX_CAMERAS:
        raise ValueError(f"{len(rig)} cameras; the points table holds at most {MAX_CAMERAS}")
    everyone = tuple(rig.names)
    zones = tuple(site.zones) if site is not None else ()
    seeing = {z.name: cameras_seeing(z, rig) for z in zones}
    rules = tuple(site.rules) if site is not None else ()
    pts = _service_points(everyone, commands)
    pts += _zone_points(zones, seeing, commands)
    pts += _rule_points(rules, zones, seeing, everyone)
    if site is not None:
        pts += _ticket_points()
    return PointsTable(pts)


def _ticket_points() -> list[Point]:
    """Each ticket slot's points: active, a deviation's incident active, its steps done."""
    pts: list[Point] = []
    for s in range(1, TICKET_SLOTS + 1):
        base, slot = TICKET_BASE + 10 * s, str(s)
        pts += [
            Point(
                base + TICKET_ACTIVE,
                SINGLE,
                f"ticket slot {s}: active",
                f"a work or operation ticket active in slot {s} (its id: /api/tickets)",
                "ticket_active",
                slot,
            ),
            Point(
                base + TICKET_DEVIATION,
                SINGLE,
                f"ticket slot {s}: deviation",
                f"an incident of the ticket in slot {s} not closed: active, or not yet "
                "acknowledged (a step out of order, in the wrong position or timed out, the "
                "supervisor absent, someone alone in the room)",
                "ticket_deviation",
                slot,
            ),
            Point(
                base + TICKET_STEPS,
                COUNT,
                f"ticket slot {s}: steps done",
                f"the steps done of the ticket in slot {s}",
                "ticket_steps",
                slot,
            ),
        ]
    return pts


def _service_points(everyone: tuple[str, ...], commands: bool) -> list[Point]:
    """The service's, the priorities' commands and the cameras' points."""
    pts = [
        Point(
            SERVICE_RUNNING,
            SINGLE,
            "service: running",
            "on while serve's frame loop steps; off at service_stalled and at a stop",
            "service_running",
        ),
        Point(
            SERVICE_DEGRADED,
            SINGLE,
            "service: degraded",
            "the health state: on while "
            "/api/health is not ok (a camera down or slow, an output failing, a stall)",
            "service_degraded",
        ),
        Point(
            PEOPLE,
            COUNT,
            "people on site",
            "people tracked in the latest step; " + _quality(everyone, False),
            "people",
            cameras=everyone,
        ),
        Point(
            UNACKNOWLEDGED,
            COUNT,
            "incidents unacknowledged",
            "the incident book: incidents active or cleared and not yet acknowledged",
            "unacknowledged",
        ),
    ]
    if commands:
        for p, label in PRIORITIES.items():
            pts.append(
                Point(
                    PRIORITY_BASE + p,
                    COMMAND,
                    f"acknowledge priority {p} ({label})",
                    f"command ON: acknowledges every unacknowledged incident of priority {p}",
                    "ack_priority",
                    str(p),
                )
            )
    for n, name in enumerate(everyone, start=1):
        pts.append(
            Point(
                CAMERA_BASE + n,
                SINGLE,
                f"camera {name}: up",
                f"camera_down / camera_up events of camera {name}; invalid while the "
                "service stalled",
                "camera_up",
                name,
            )
        )
    return pts


def _zone_points(zones: tuple, seeing: dict, commands: bool) -> list[Point]:
    """Each zone's points (occupied, alarm; its acknowledge command)."""
    pts: list[Point] = []
    for n, z in enumerate(zones, start=1):
        cams, base = seeing[z.name], ZONE_BASE + 10 * n
        q = _quality(cams, not cams)
        pts += [
            Point(
                base + ZONE_OCCUPIED,
                SINGLE,
                f"zone {z.name} ({z.kind}): occupied",
                f"enter / exit events of zone {z.name}; {q}",
                "zone_occupied",
                z.name,
                cams,
                not cams,
            ),
            Point(
                base + ZONE_ALARM,
                SINGLE,
                f"zone {z.name} ({z.kind}): alarm active",
                f"incidents of zone {z.name} active or acknowledged, not cleared; {q}",
                "zone_alarm",
                z.name,
                cams,
                not cams,
            ),
        ]
        if z.power is not None:
            pts.append(
                Point(
                    base + ZONE_LIVE,
                    SINGLE,
                    f"zone {z.name} ({z.kind}): live",
                    f"the state stereopose holds of zone {z.name} from its breakers and "
                    "earthing switches: on live, off dead; invalid while unknown (counted live)",
                    "zone_live",
                    z.name,
                )
            )
        if commands:
            pts.append(
                Point(
                    base + ZONE_ACK,
                    COMMAND,
                    f"zone {z.name}: acknowledge",
                    f"command ON: acknowledges every unacknowledged incident of zone {z.name}",
                    "ack_zone",
                    z.name,
                )
            )
    return pts


def _rule_points(
    rules: tuple, zones: tuple, seeing: dict, everyone: tuple[str, ...]
) -> list[Point]:
    """Each behaviour rule's alarm point, its quality from the cameras of its zones."""
    pts: list[Point] = []
    for n, r in enumerate(rules, start=1):
        watched = watched_zones(r, zones)
        if watched is None:
            cams, unseen = everyone, False
        else:
            cams = tuple(c for c in everyone if any(c in seeing.get(z, ()) for z in watched))
            unseen = not cams
        pts.append(
            Point(
                RULE_BASE + 10 * n + RULE_ALARM,
                SINGLE,
                f"rule {r.name} ({r.type}): alarm active",
                f"incidents of behaviour rule {r.name} active or acknowledged, not "
                f"cleared; {_quality(cams, unseen)}",
                "rule_alarm",
                r.name,
                cams,
                unseen,
            )
        )
    return pts
