"""Warnings on site: at each step, the hazards of the energized zones (someone inside or
within the approach margin, as the fences' debounced state holds it) said on the speakers
that cover their zones and shown by the signals' coils, while they last.

    warner = Warner(site.zones, settings, book, speakers, signals, safe=lambda: {...})
    events = warner.step(t, frame, people, fences)      # once per step, after the fences

A hazard warns only when:
- its zone is energized and warns on site (`on_site`, true by default), and not safe now
  (`safe()`: dead by its breakers, or isolated by the running ticket);
- its priority (the zone's, or critical for inside and high for an approach) is one of
  [warnings] priorities;
- its person is seen at this step, not only predicted.

Each speaker says the most urgent of its zones' hazards (then the nearest): "Stop. 110 kV
busbar, 0.6 metres, to your left", the side from the worker's skeleton (where the nearest
point of the zone is, against the way his shoulders face). Each signal's coils are on while a
hazard of its zones with one of its priorities lasts, off within a step of its end. Nothing
here waits: the speakers and signals have threads of their own (onsite.rtp, onsite.modbus);
what is said now is in `now()` and, when it changes, in `publish` (MQTT's `warnings`).

A signal that stops answering is a `warning_output_down` event (kind "service", its name in
`source`) and `warning_output_back` when it answers again: one incident while it is down.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable, Collection, Mapping, Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from stereopose.alarms.priority import default_priority
from stereopose.onsite.modbus import Signal
from stereopose.onsite.phrases import Phrasebook
from stereopose.onsite.rtp import Speaker
from stereopose.onsite.settings import WarningSettings
from stereopose.skeleton import floor_position, heading_deg
from stereopose.types import Event, People3D
from stereopose.zones import Zone, ZoneGeometry

__all__ = ["Hazard", "Warner", "side_of"]

AHEAD_DEG = 45.0  # within this of the way he faces: ahead (beyond 180 - this: behind)
SERVICE_KIND = "service"


@dataclass(frozen=True)
class Hazard:
    """A person's hazard now: inside (`enter`) or near (`approach`) an energized zone;
    distance_m of his nearest triggering joint; side: where the zone is for him."""

    zone: str
    person: int
    kind: str
    priority: int
    distance_m: float
    side: str

    def as_dict(self) -> dict:
        return {
            "zone": self.zone,
            "person": self.person,
            "kind": self.kind,
            "priority": self.priority,
            "distance_m": round(self.distance_m, 2),
            "side": self.side,
        }


class Occupancy(Protocol):
    """What the warner needs of the fences (fence.rules.FenceMonitor.occupants)."""

    def occupants(self, zone: str) -> tuple[list, list]: ...


def side_of(toward: np.ndarray, heading: float) -> str:
    """Where a floor direction `toward` (2,) lies for someone facing `heading` degrees
    (counter-clockwise from world +x): ahead, behind, left, right; nearby when either is
    unknown or the direction has no length."""
    if not np.isfinite(toward).all() or not math.isfinite(heading) or np.hypot(*toward) < 1e-6:
        return "nearby"
    a = (math.degrees(math.atan2(toward[1], toward[0])) - heading + 180.0) % 360.0 - 180.0
    if abs(a) <= AHEAD_DEG:
        return "ahead"
    if abs(a) >= 180.0 - AHEAD_DEG:
        return "behind"
    return "left" if a > 0 else "right"


def _nearest_on_polygon(p: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """The point of polygon `poly` (V, 2) nearest to floor point p (2,) (its edges)."""
    a, b = poly, np.roll(poly, -1, axis=0)
    ab = b - a
    t = np.clip(((p - a) * ab).sum(1) / np.maximum((ab**2).sum(1), 1e-12), 0.0, 1.0)
    q = a + t[:, None] * ab
    return q[np.argmin(((q - p) ** 2).sum(1))]


class Warner:
    """See the module. zones: the site's; book: its messages; speakers and signals by name;
    safe(): the zones safe now; publish(doc): the warnings now, each time they change (MQTT);
    clock: for the events' onset (the step's t is used)."""

    def __init__(
        self,
        zones: Sequence[Zone],
        settings: WarningSettings,
        book: Phrasebook,
        speakers: Mapping[str, Speaker],
        signals: Mapping[str, Signal],
        safe: Callable[[], Collection[str]] = lambda: (),
        publish: Callable[[dict], None] | None = None,
    ) -> None:
        self.settings, self.book = settings, book
        self.speakers, self.signals = dict(speakers), dict(signals)
        self.safe, self.publish = safe, publish
        self.zones = tuple(z for z in zones if z.kind == "energized" and z.on_site)
        self.geometry = ZoneGeometry(self.zones) if self.zones else None
        self._lock = threading.Lock()
        self._health: list[tuple[str, bool, str]] = []  # from the signals' threads
        self._now: list[Hazard] = []
        self._said: dict[str, Hazard | None] = dict.fromkeys(self.speakers)
        self._coils: dict[str, bool] = dict.fromkeys(self.signals, False)
        self._last_doc: str | None = None
        self.figures = {"hazards": 0, "messages": 0, "publish_failures": 0}

    def on_health(self, name: str, up: bool, why: str) -> None:
        """A signal's health changed (its thread): an event at the next step."""
        with self._lock:
            if len(self._health) < 256:
                self._health.append((name, up, why))

    # -- the step ---------------------------------------------------------------------------

    def hazards(self, people: People3D, fences: Occupancy) -> list[Hazard]:
        """The hazards now (see the module), most urgent first, then nearest."""
        if self.geometry is None or not len(people):
            return []
        seen = ~np.asarray(people.predicted, bool)
        rows = {int(i): r for r, i in enumerate(people.ids) if seen[r]}
        if not rows:
            return []
        safe = set(self.safe())
        floors = floor_position(people.joints)
        headings = heading_deg(people.joints)
        out = []
        for k, zone in enumerate(self.zones):
            if zone.name in safe:
                continue
            inside, near = fences.occupants(zone.name)
            for kind, members in (("enter", inside), ("approach", near)):
                priority = zone.priority or default_priority("energized", kind)
                if priority not in self.settings.priorities:
                    continue
                for pid, _ in members:
                    r = rows.get(int(pid))
                    if r is None:
                        continue  # only predicted, or not in this step's people
                    out.append(self._hazard(zone, k, kind, priority, people, r, floors, headings))
        out.sort(key=lambda h: (h.priority, h.distance_m))
        return out

    def _hazard(self, zone, k, kind, priority, people, r, floors, headings) -> Hazard:
        J = people.joints[r][list(zone.joints)]
        _, dist = self.geometry.test(J[None], np.array([k]))
        d = float(np.min(dist)) if np.isfinite(dist).any() else float(zone.margin_m)
        floor = floors[r]
        if kind == "enter" or not np.isfinite(floor).all():
            side = "nearby"
        else:
            poly = zone.polygon
            toward = _nearest_on_polygon(floor, poly) - floor
            side = side_of(toward, float(headings[r]))
        return Hazard(zone.name, int(people.ids[r]), kind, int(priority), d, side)

    def step(self, t: float, frame: int, people: People3D, fences: Occupancy) -> list[Event]:
        """This step's hazards to the speakers and signals; the signals' health events."""
        hazards = self.hazards(people, fences)
        self._now = hazards
        self.figures["hazards"] += len(hazards)
        for name, speaker in self.speakers.items():
            mine = [h for h in hazards if h.zone in speaker.spec.zones]
            if not mine:
                if self._said.get(name) is not None:
                    speaker.quiet()
                self._said[name] = None
                continue
            h = mine[0]
            before = self._said.get(name)
            words = (h.zone, h.kind, h.person, round(h.distance_m, 1), h.side)
            if before is None or words != (
                before.zone, before.kind, before.person, round(before.distance_m, 1), before.side
            ):  # fmt: skip
                pcm = self.book.message(h.zone, h.kind, h.distance_m, h.side)
                speaker.want((h.zone, h.kind, h.person), h.priority, pcm)
            if before is None or before.zone != h.zone:
                self.figures["messages"] += 1
            self._said[name] = h
        for name, signal in self.signals.items():
            spec = signal.spec
            on = any(h.zone in spec.zones and h.priority in spec.priorities for h in hazards)
            self._coils[name] = on
            signal.want(signal.coils if on else ())
        self._tell(t)
        return self._health_events(t, frame)

    def now(self) -> dict:
        """What warns on site now: each hazard with the speakers and signals that give it."""
        out = []
        for h in self._now:
            d = h.as_dict()
            d["speakers"] = [n for n, s in self._said.items() if s == h]
            d["signals"] = [
                n
                for n, g in self.signals.items()
                if self._coils.get(n) and h.zone in g.spec.zones and h.priority in g.spec.priorities
            ]
            out.append(d)
        return {"warnings": out}

    def _tell(self, t: float) -> None:
        if self.publish is None:
            return
        doc = self.now()
        key = repr(doc)
        if key == self._last_doc:
            return
        self._last_doc = key
        try:
            self.publish({**doc, "t": round(float(t), 3)})
        except Exception:  # an output's failure never stops a step
            self.figures["publish_failures"] += 1

    def _health_events(self, t: float, frame: int) -> list[Event]:
        with self._lock:
            told, self._health = self._health, []
        return [
            Event(
                t=t,
                frame=frame,
                person=-1,
                zone="",
                kind=SERVICE_KIND,
                type="warning_output_back" if up else "warning_output_down",
                onset_t=t,
                source=name,
            )
            for name, up, _why in told
        ]

    def close(self) -> None:
        """Every speaker quiet and every coil off, their threads ended."""
        for s in self.speakers.values():
            s.close()
        for g in self.signals.values():
            g.close()
