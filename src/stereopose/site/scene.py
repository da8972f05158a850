"""The console's scene: the latest people with their floor points, headings, postures and
trails, and each zone's state (free, occupied, alarm) with who is inside.

`SceneState.update(frame, wall_start)` is called by the frame loop (through the live hub): it
keeps a reference to the frame's people (NumPy only, no JSON), extends each person's trail and
follows the zones from the step's events (enter, exit, approach) and, for an energized zone,
from whoever has a triggering joint inside it now (the enter event waits for its debounce).
`people()` and `zones()` are the /api/people and /api/zones bodies, read by the web side.
Bounded: TRAIL_POINTS per person, TRAIL_S long, MAX_TRAILS people.
"""

from __future__ import annotations

import math
import threading
from collections import deque
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from stereopose.behaviour.posture import Posture
from stereopose.fence import Site, ZoneGeometry
from stereopose.io.sinks.base import FrameResult
from stereopose.skeleton import floor_position, heading_deg

if TYPE_CHECKING:
    from stereopose.types import Event

__all__ = ["ALARM_HOLD_S", "MAX_TRAILS", "TRAIL_POINTS", "TRAIL_S", "SceneState", "rounded"]

TRAIL_S = 5.0
TRAIL_POINTS = 50
MAX_TRAILS = 256
ALARM_HOLD_S = 3.0  # an approach keeps its zone in alarm this long


@dataclass(frozen=True)
class Latest:
    """The latest step's people, as the scene keeps them."""

    frame: int
    t: float
    wall_t: float
    ids: np.ndarray
    joints: np.ndarray
    positions: np.ndarray
    headings: np.ndarray
    postures: Mapping[int, Posture] | None = None  # by person id


def rounded(x: float, nd: int = 3) -> float | None:
    """x rounded to nd decimals for JSON; None when not finite."""
    return round(float(x), nd) if math.isfinite(x) else None


class SceneState:
    """See the module. site: the zones (None: none); power(): the energized zones' states
    from their breakers now (zones.power_state's snapshot; None: none read)."""

    def __init__(self, site: Site | None, power: Callable[[], dict] | None = None) -> None:
        zones = site.zones if site is not None else ()
        self.zones_by_name = {z.name: z for z in zones}
        self.power = power
        self._lock = threading.Lock()
        self.latest: Latest | None = None
        self._trails: dict[int, deque[tuple[float, float, float]]] = {}
        self._trail_seen: dict[int, float] = {}
        self._inside: dict[str, set[int]] = {z.name: set() for z in zones}
        self._energized = tuple(z for z in zones if z.kind == "energized")
        self._geometry = ZoneGeometry(self._energized) if self._energized else None
        self._touching: dict[str, frozenset[int]] = {}
        self._approach: dict[str, float] = {}  # zone -> service time of its last approach
        self._off: set[str] = set()  # zones switched off (zone_disabled; zone_enabled: on)
        self.version = 0  # raised at each change of a zone's occupants or alarm

    def set_site(self, site: Site | None) -> None:
        """A new site's zones (the frame loop's thread, at a step's start): who is inside a
        zone kept stays; the zones are sent again."""
        zones = site.zones if site is not None else ()
        energized = tuple(z for z in zones if z.kind == "energized")
        with self._lock:
            self.zones_by_name = {z.name: z for z in zones}
            self._inside = {z.name: self._inside.get(z.name, set()) for z in zones}
            self._off &= set(self.zones_by_name)  # a zone switched off stays so (the fences')
            self._energized = energized
            self._geometry = ZoneGeometry(energized) if energized else None
            self._touching = {}
            self.version += 1

    # -- the frame loop's side ------------------------------------------------------------

    def update(self, frame: FrameResult, wall_start: float) -> None:
        """One step (see the module); quick, never blocks on the web side."""
        p = frame.people3d
        joints = np.asarray(p.joints, float)
        ids = np.asarray(p.ids)
        if len(ids):
            positions, headings = floor_position(joints), heading_deg(joints)
        else:
            positions, headings = np.zeros((0, 2)), np.zeros(0)
        t = float(frame.t)
        latest = Latest(
            int(frame.frame),
            t,
            wall_start + t,
            ids,
            joints,
            positions,
            headings,
            frame.postures,
        )
        touching = self._touching_now(joints, ids)
        with self._lock:
            self.latest = latest
            self._trail(t, ids, positions)
            if touching != self._touching:
                self._touching = touching
                self.version += 1
            if frame.events:
                self._occupancy(frame.events, t)

    def _touching_now(self, joints: np.ndarray, ids: np.ndarray) -> dict[str, frozenset[int]]:
        """Energized zone -> the ids with one of its triggering joints inside it (joints
        (P, 17, 3) metres)."""
        if self._geometry is None or not len(ids) or joints.ndim != 3:
            return {}
        P, J = joints.shape[:2]
        inside = self._geometry.inside(joints.reshape(-1, 3)).reshape(P, J, -1)
        out = {}
        for k, z in enumerate(self._energized):
            rows = np.flatnonzero(inside[:, list(z.joints), k].any(axis=1))
            if len(rows):
                out[z.name] = frozenset(int(i) for i in ids[rows])
        return out

    def _trail(self, t: float, ids: np.ndarray, positions: np.ndarray) -> None:
        step = TRAIL_S / TRAIL_POINTS
        for pid, (x, y) in zip(ids.tolist(), positions.tolist(), strict=True):
            if not (math.isfinite(x) and math.isfinite(y)):
                continue
            trail = self._trails.get(pid)
            if trail is None:
                if len(self._trails) >= MAX_TRAILS:
                    continue
                trail = self._trails[pid] = deque(maxlen=TRAIL_POINTS)
            if not trail or t - trail[-1][0] >= step - 1e-6:
                trail.append((t, x, y))
            while trail[0][0] < t - TRAIL_S - 1e-6:
                trail.popleft()
            self._trail_seen[pid] = t
        for pid in [k for k, seen in self._trail_seen.items() if t - seen > TRAIL_S]:
            self._trails.pop(pid, None)
            self._trail_seen.pop(pid, None)

    def _occupancy(self, events: Sequence[Event], t: float) -> None:
        for e in events:
            inside = self._inside.get(e.zone)
            if inside is None:
                continue
            if e.type == "enter":
                inside.add(e.person)
            elif e.type == "exit":
                inside.discard(e.person)
            elif e.type == "approach":
                self._approach[e.zone] = t
            elif e.type in ("zone_disabled", "zone_enabled"):
                (self._off.add if e.type == "zone_disabled" else self._off.discard)(e.zone)
            else:
                continue
            self.version += 1

    # -- the web side's reads --------------------------------------------------------------

    def trails(self) -> int:
        """How many people's trails are kept."""
        with self._lock:
            return len(self._trails)

    def people(self) -> dict:
        """The /api/people body of the latest frame."""
        with self._lock:
            latest = self.latest
            trails = {pid: list(tr) for pid, tr in self._trails.items()}
            inside = self._occupants()
        if latest is None:
            return {"frame": None, "t": None, "wall_t": None, "people": []}
        people = []
        postures = latest.postures or {}
        for row, pid in enumerate(latest.ids.tolist()):
            posture = postures.get(pid)
            x, y = latest.positions[row].tolist()
            joints = [
                [round(a, 3), round(b, 3), round(c, 3)]
                if math.isfinite(a) and math.isfinite(b) and math.isfinite(c)
                else None
                for a, b, c in latest.joints[row].tolist()
            ]
            people.append(
                {
                    "id": int(pid),
                    "position": [rounded(x), rounded(y), 0.0] if math.isfinite(x + y) else None,
                    "heading_deg": rounded(float(latest.headings[row]), 1),
                    "joints": joints,
                    "zones": sorted(z for z, ids in inside.items() if pid in ids),
                    "trail": [[round(px, 3), round(py, 3)] for _, px, py in trails.get(pid, [])],
                    "posture": None if posture is None else posture.posture,
                    "flags": [] if posture is None else [str(f) for f in posture.flags],
                }
            )
        return {
            "frame": latest.frame,
            "t": round(latest.t, 3),
            "wall_t": round(latest.wall_t, 3),
            "people": people,
        }

    def _occupants(self) -> dict[str, set[int]]:
        """Zone -> who is inside: by its enter and exit events, and for an energized zone
        also whoever has a triggering joint in it now (under the lock)."""
        return {z: ids | self._touching.get(z, frozenset()) for z, ids in self._inside.items()}

    def zones(self) -> dict:
        """The /api/zones body: each zone with its state and who is inside."""
        with self._lock:
            inside = {z: sorted(ids) for z, ids in self._occupants().items()}
            approach = dict(self._approach)
            now_t = self.latest.t if self.latest is not None else 0.0
            off = set(self._off)
        power = self.power() if self.power is not None else {}
        out = []
        for name, z in self.zones_by_name.items():
            occupants = inside.get(name, [])
            recent = now_t - approach.get(name, -math.inf) <= ALARM_HOLD_S
            dead = power.get(name, {}).get("state") == "dead"
            if name in off:  # switched off: no alarm of its own, whoever stands in it
                state = "off"
            elif z.kind == "energized" and (occupants or recent) and not dead:
                state = "alarm"
            else:
                state = "occupied" if occupants else "free"
            out.append(
                {
                    "name": name,
                    "kind": z.kind,
                    "polygon": [[round(float(x), 3), round(float(y), 3)] for x, y in z.polygon],
                    "z": [float(z.z[0]), float(z.z[1])],
                    "margin_m": float(z.margin_m),
                    "state": state,
                    "occupants": occupants,
                    # live, dead or unknown, its source and since when (null: no source)
                    "power": power.get(name),
                    "voltage_kv": z.voltage_kv,
                    "enabled": name not in off,  # false: switched off (docs/mqtt.md)
                }
            )
        return {"zones": out}
