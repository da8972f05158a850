"""Calls on site: the messages that are not an energized zone's hazard. A person down (a call
for help on the speakers near him, while he is down), a ticket's step done in the wrong
position (said once near the step), and an admin's test of a speaker or a signal.

    calls = Calls(settings, zones)
    calls.take(t, step_events, people)       # each step: calls opened and ended
    calls.test("bay1_pa", t, speaker=True, duration_s=2.1)
    for call in calls.now(t): ...            # the calls of this step, most urgent first

Which speakers are near a place (`near`): those hung within NEAR_M of it (their `position`),
else those covering a zone within NEAR_M of it, else every speaker: a call for help is better
heard too widely than not at all. A wrong position is said on the speakers covering the
step's position zone, else near the operator. A call lasts while its cause does (person_up,
or his track ended), at most MAX_CALL_S; a one-off message for the time it takes to say.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field

import numpy as np

from stereopose.alarms.priority import default_priority
from stereopose.onsite.settings import SpeakerSpec, WarningSettings
from stereopose.types import Event, People3D
from stereopose.zones import Zone

__all__ = ["TEST_PRIORITY", "Call", "Calls", "near", "nearest_on_polygon"]

NEAR_M = 20.0
MAX_CALL_S = 600.0
MAX_CALLS = 64  # calls open at once, at most (more: the newest not taken)
TEST_PRIORITY = 5  # below every alarm's (1-4): a test never cuts into a warning
_ENDS = {"person_down": "person_up"}


@dataclass
class Call:
    """A call on site: message `kind` on `speakers` (and, for a test, `signals`) at
    `priority` until the step time `until`; lasting: until its end event."""

    key: tuple
    kind: str
    priority: int
    speakers: frozenset[str]
    until: float
    person: int = -1
    signals: frozenset[str] = field(default_factory=frozenset)
    lasting: bool = False

    def as_dict(self) -> dict:
        return {"kind": self.kind, "priority": self.priority, "person": self.person}


def _inside(p: np.ndarray, poly: np.ndarray) -> bool:
    x, y = p
    xs, ys = poly[:, 0], poly[:, 1]
    xj, yj = np.roll(xs, 1), np.roll(ys, 1)
    crosses = ((ys > y) != (yj > y)) & (
        x < (xj - xs) * (y - ys) / np.where(yj == ys, 1e-12, yj - ys) + xs
    )
    return bool(np.count_nonzero(crosses) % 2)


def nearest_on_polygon(p: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """The point of polygon `poly` (V, 2) nearest to floor point p (2,) (its edges)."""
    a, b = poly, np.roll(poly, -1, axis=0)
    ab = b - a
    t = np.clip(((p - a) * ab).sum(1) / np.maximum((ab**2).sum(1), 1e-12), 0.0, 1.0)
    q = a + t[:, None] * ab
    return q[np.argmin(((q - p) ** 2).sum(1))]


def _floor_distance(p: np.ndarray, poly: np.ndarray) -> float:
    """Metres from floor point p to polygon `poly` (0 inside)."""
    if _inside(p, poly):
        return 0.0
    return float(np.hypot(*(nearest_on_polygon(p, poly) - p)))


def near(
    position: Sequence[float] | None, speakers: Sequence[SpeakerSpec], zones: Sequence[Zone]
) -> frozenset[str]:
    """The speakers near floor point `position` (see the module); every one when unknown."""
    every = frozenset(s.name for s in speakers)
    if position is None or not np.isfinite(np.asarray(position, float)).all():
        return every
    p = np.asarray(position, float)[:2]
    hung = {
        s.name
        for s in speakers
        if s.position is not None and np.hypot(*(np.asarray(s.position) - p)) <= NEAR_M
    }
    if hung:
        return frozenset(hung)
    close = {z.name for z in zones if _floor_distance(p, np.asarray(z.polygon, float)) <= NEAR_M}
    covering = {s.name for s in speakers if close & set(s.zones)}
    return frozenset(covering) or every


class Calls:
    """The calls of a site's warnings (see the module)."""

    def __init__(self, settings: WarningSettings, zones: Sequence[Zone]) -> None:
        self.settings, self.zones = settings, tuple(zones)
        self._open: dict[tuple, Call] = {}
        self.dropped = 0  # calls not taken: MAX_CALLS were open

    def _add(self, call: Call) -> None:
        if call.key not in self._open and len(self._open) >= MAX_CALLS:
            self.dropped += 1
            return
        self._open[call.key] = call

    def take(
        self, t: float, events: Iterable[Event], people: People3D, one_off_s: float = 4.0
    ) -> None:
        """The step's events: calls opened (their kinds in [warnings] calls) and ended.
        one_off_s: how long a one-off message takes to say (its call's length)."""
        wanted = set(self.settings.calls)
        speakers = self.settings.speakers
        for e in events:
            if e.type in wanted and e.type == "person_down":
                self._add(
                    Call(
                        ("person_down", e.person),
                        "person_down",
                        default_priority("behaviour", "person_down"),
                        near(e.position, speakers, self.zones),
                        t + MAX_CALL_S,
                        person=e.person,
                        lasting=True,
                    )
                )
            elif e.type in wanted and e.type == "step_wrong_position":
                covering = frozenset(s.name for s in speakers if e.zone and e.zone in s.zones)
                self._add(
                    Call(
                        ("step_wrong_position", e.ticket, e.step),
                        "step_wrong_position",
                        default_priority("ticket", "step_wrong_position"),
                        covering or near(e.position, speakers, self.zones),
                        t + one_off_s,
                        person=e.person,
                    )
                )
            elif e.type in _ENDS.values():
                for key, call in list(self._open.items()):
                    if call.lasting and _ENDS.get(call.kind) == e.type and call.person == e.person:
                        del self._open[key]
        seen = {int(i) for i in people.ids} if len(people) else set()
        for key, call in list(self._open.items()):  # his track ended: nobody left to help
            if call.lasting and call.person not in seen:
                del self._open[key]

    def test(self, output: str, t: float, speaker: bool, duration_s: float) -> None:
        """A test of `output` (a speaker: its message; a signal: its coils) for duration_s."""
        call = Call(
            ("test", output),
            "test",
            TEST_PRIORITY,
            frozenset({output}) if speaker else frozenset(),
            t + duration_s,
            signals=frozenset() if speaker else frozenset({output}),
        )
        self._add(call)

    def now(self, t: float) -> list[Call]:
        """The calls of this step (those past their time ended), most urgent first."""
        for key, call in list(self._open.items()):
            if t >= call.until:
                del self._open[key]
        return sorted(self._open.values(), key=lambda c: c.priority)
