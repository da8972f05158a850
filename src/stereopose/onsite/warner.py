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
from stereopose.onsite.audio import RATE
from stereopose.onsite.calls import TEST_PRIORITY, Call, Calls, nearest_on_polygon
from stereopose.onsite.control import output_event
from stereopose.onsite.modbus import Signal
from stereopose.onsite.phrases import Phrasebook
from stereopose.onsite.rtp import Speaker
from stereopose.onsite.settings import CALLS, WarningSettings
from stereopose.skeleton import floor_position, heading_deg
from stereopose.types import Event, People3D
from stereopose.zones import Zone, ZoneGeometry

__all__ = ["Hazard", "Warner", "side_of"]

AHEAD_DEG = 45.0  # within this of the way he faces: ahead (beyond 180 - this: behind)
PULSE_S = 3.0  # a signal's test: its coils on this long


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


@dataclass(frozen=True)
class _Said:
    """What a speaker says: its message's key and priority, the words it is made of (new
    words: the message again), and the hazard or call it tells."""

    key: tuple
    priority: int
    words: tuple
    item: Hazard | Call


class Occupancy(Protocol):
    """What the warner needs of the fences (fence.rules.FenceMonitor.occupants)."""

    def occupants(
        self, zone: str
    ) -> tuple[list[tuple[int, np.ndarray]], list[tuple[int, np.ndarray]]]: ...


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
        self._said: dict[str, _Said | None] = dict.fromkeys(self.speakers)
        self.calls = Calls(settings, zones)
        self._calls_now: list[Call] = []
        self._silenced: frozenset[str] = frozenset()
        # how long a one-off call takes to say: its longest message, and a breath
        self._one_off_s = max(len(book.message(None, k)) for k in CALLS) / RATE + 0.1
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

    def _hazard(
        self,
        zone: Zone,
        k: int,
        kind: str,
        priority: int,
        people: People3D,
        r: int,
        floors: np.ndarray,
        headings: np.ndarray,
    ) -> Hazard:
        assert self.geometry is not None  # hazards() asks only where there are zones
        J = people.joints[r][list(zone.joints)]
        _, dist = self.geometry.test(J[None], np.array([k]))
        d = float(np.min(dist)) if np.isfinite(dist).any() else float(zone.margin_m)
        floor = floors[r]
        if kind == "enter" or not np.isfinite(floor).all():
            side = "nearby"
        else:
            poly = zone.polygon
            toward = nearest_on_polygon(floor, poly) - floor
            side = side_of(toward, float(headings[r]))
        return Hazard(zone.name, int(people.ids[r]), kind, int(priority), d, side)

    def step(
        self,
        t: float,
        frame: int,
        people: People3D,
        fences: Occupancy,
        events: Sequence[Event] = (),
        silenced: Collection[str] = (),
    ) -> list[Event]:
        """This step's hazards and calls (the step's earlier `events`: a person down, a step
        in the wrong position; the admin's tests) to the speakers and signals, except those
        `silenced`; the outputs' health events."""
        hazards = self.hazards(people, fences)
        self._now = hazards
        self.figures["hazards"] += len(hazards)
        self.calls.take(t, events, people, self._one_off_s)
        calls = self.calls.now(t)
        self._calls_now = calls
        self._silenced = frozenset(silenced)
        for name, speaker in self.speakers.items():
            said = None if name in self._silenced else self._choose(name, hazards, calls)
            before = self._said.get(name)
            self._said[name] = said
            if said is None:
                if before is not None:
                    speaker.quiet()
                continue
            if before is None or said.words != before.words:
                speaker.want(said.key, said.priority, self._message(said.item))
            if before is None or before.key != said.key:
                self.figures["messages"] += 1
        for name, signal in self.signals.items():
            spec = signal.spec
            on = name not in self._silenced and (
                any(h.zone in spec.zones and h.priority in spec.priorities for h in hazards)
                or any(name in c.signals for c in calls)
            )
            self._coils[name] = on
            signal.want(signal.coils if on else ())
        self._tell(t)
        return self._health_events(t, frame)

    def _choose(self, name: str, hazards: list[Hazard], calls: list[Call]) -> _Said | None:
        """What speaker `name` says now: the most urgent of its zones' hazards (then the
        nearest) and its calls, a hazard before a call of the same priority."""
        zones = self.speakers[name].spec.zones
        h = next((h for h in hazards if h.zone in zones), None)
        c = next((c for c in calls if name in c.speakers), None)
        if h is not None and (c is None or h.priority <= c.priority):
            words = (h.zone, h.kind, h.person, round(h.distance_m, 1), h.side)
            return _Said((h.zone, h.kind, h.person), h.priority, words, h)
        if c is not None:
            return _Said(c.key, c.priority, c.key, c)
        return None

    def _message(self, item: Hazard | Call) -> np.ndarray:
        if isinstance(item, Hazard):
            return self.book.message(item.zone, item.kind, item.distance_m, item.side)
        return self.book.message(None, item.kind)

    def test(self, output: str, t: float) -> None:
        """A test of speaker or signal `output` at this step's time `t` (see onsite.calls):
        a speaker says the test message once, a signal's coils pulse for PULSE_S."""
        if output in self.speakers:
            self.calls.test(output, t, True, len(self.book.message(None, "test")) / RATE + 0.1)
        elif output in self.signals:
            self.calls.test(output, t, False, PULSE_S)

    def sounding(self, output: str) -> bool:
        """Whether `output` warns or calls now (a test is refused meanwhile)."""
        said = self._said.get(output)
        return (said is not None and said.priority < TEST_PRIORITY) or (
            self._coils.get(output, False) and not any(output in c.signals for c in self._calls_now)
        )

    def now(self) -> dict:
        """What warns on site now: each hazard and call with the speakers and signals that
        give it."""
        out = []
        for h in self._now:
            d = h.as_dict()
            d["speakers"] = [n for n, s in self._said.items() if s is not None and s.item == h]
            d["signals"] = [
                n
                for n, g in self.signals.items()
                if self._coils.get(n) and h.zone in g.spec.zones and h.priority in g.spec.priorities
            ]
            out.append(d)
        calls = []
        for c in self._calls_now:
            d = c.as_dict()
            d["speakers"] = [n for n, s in self._said.items() if s is not None and s.item is c]
            d["signals"] = [n for n in c.signals if self._coils.get(n)]
            calls.append(d)
        return {"warnings": out, "calls": calls}

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
            output_event(t, frame, "warning_output_back" if up else "warning_output_down", name)
            for name, up, _why in told
        ]

    def close(self) -> None:
        """Every speaker quiet and every coil off, their threads ended."""
        for s in self.speakers.values():
            s.close()
        for g in self.signals.values():
            g.close()
