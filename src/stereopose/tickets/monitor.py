"""One ticket checked frame by frame while it is active.

Roles: the operator is the ticket's person id, or ("auto") the first person whose feet stand
in a step's position (the first step's before the others) or whose hand is in a step's target;
the supervisor is the ticket's id, or ("auto") the nearest other person within `supervise_m`
of the operator. A binding follows its person's id; an "auto" binding whose person has not
been seen for REBIND_S is let go and made again.

A step's action is the operator's hand (both hands: `both_hands`) inside its target zone for
`hold_s` (gaps up to GAP_S bridged). When it completes:
- step_out_of_order (alarm) if an earlier step, not optional, is not done yet (the step still
  counts as done);
- step_wrong_position (alarm) if the operator's feet were outside its position, or the
  step's facing or posture failed (`failed` names which);
- step_done (info) with when (onset_t: the action's start), where (the operator's floor
  position) and how long (duration_s: the action's).
step_timeout (alarm): a step not done `max_s` after the previous step was done (the first:
after the ticket's start). supervisor_absent (alarm): the supervisor farther than supervise_m
from the operator, or out of view, for absent_s while the operator is seen (ends
with supervisor_back). lone_in_room (alarm): one person only seen for lone_s (ends with
lone_in_room_end). ticket_completed (info), once, when the ticket ends: its `result`.

Every event has kind "ticket", the ticket's id in `ticket`, the step's name in `step` where it
concerns one, and the operator as its person (-1 before one is bound).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field
from typing import TypedDict, Unpack

import numpy as np

from stereopose.skeleton import LEFT_WRIST, RIGHT_WRIST, floor_position, heading_deg
from stereopose.tickets.ticket import Ticket, TicketStep
from stereopose.types import Event, People3D
from stereopose.zones import Zone, ZoneGeometry
from stereopose.zones.debounce import TIME_EPS, Latch

__all__ = ["TICKET_KIND", "TicketMonitor"]

TICKET_KIND = "ticket"
GAP_S = 0.4  # a hand out of the target this long at most does not break its hold
REBIND_S = 5.0  # an "auto" role's person unseen this long is let go
MAX_DEVIATIONS = 100  # the latest deviations listed (all counted)
EPS = TIME_EPS  # seconds (zones.debounce)
NEAR_EPS = 1e-6  # metres of slack on supervise_m


@dataclass
class TicketFields(TypedDict, total=False):
    """What a ticket event may carry beyond its person, zone and times."""

    step: str | None
    duration_s: float | None
    position: tuple[float, float] | None
    failed: str | None
    result: dict | None


class StepState:
    done_t: float | None = None  # when its action completed
    onset_t: float | None = None  # its action's start
    by: int | None = None
    position: tuple[float, float] | None = None
    in_order: bool = True
    failed: str = ""
    timed_out: bool = False
    # the action under way: (start, last frame inside, feet in position at every frame)
    hold: tuple[float, float, bool] | None = None


@dataclass
class Seen:
    """One frame's people, by id: floor point, both wrists, heading (degrees), posture."""

    xy: dict[int, tuple[float, float]] = field(default_factory=dict)
    wrists: dict[int, np.ndarray] = field(default_factory=dict)
    heading: dict[int, float] = field(default_factory=dict)


class TicketMonitor:
    """See the module. zones: the site's zones (every one the ticket names among them)."""

    def __init__(self, ticket: Ticket, zones: tuple[Zone, ...]) -> None:
        self.ticket, self.zones = ticket, zones  # (the site's, as the desk had them)
        by_name = {z.name: z for z in zones}
        names = sorted(ticket.zones())
        self.geometry = ZoneGeometry(tuple(by_name[n] for n in names))
        self.index = {n: k for k, n in enumerate(names)}
        self.steps = [StepState() for _ in ticket.steps]
        self.operator = ticket.operator if isinstance(ticket.operator, int) else None
        self.supervisor = ticket.supervisor if isinstance(ticket.supervisor, int) else None
        self.last_seen: dict[int, float] = {}
        self.started_t: float | None = None
        self.ended_t: float | None = None
        self.absent = Latch()  # the supervisor away from the operator (zones.debounce)
        self.lone = Latch()  # one person alone in the ticket's zones
        self.deviations: deque[dict] = deque(maxlen=MAX_DEVIATIONS)  # the latest
        self.deviation_counts: dict[str, int] = {}  # every one, by type

    # -- the frame's -----------------------------------------------------------------------

    def start(self, t: float) -> None:
        self.started_t = t

    def step(
        self, t: float, frame: int, people: People3D, postures: dict | None = None
    ) -> list[Event]:
        """The ticket's events at this frame."""
        if self.started_t is None:
            self.start(t)
        if self.ended_t is not None:
            return []
        seen = self._seen(people)
        for pid in seen.xy:
            self.last_seen[pid] = t
        self._bind(t, seen)
        out: list[Event] = []
        out += self._actions(t, frame, seen, postures or {})
        out += self._timeouts(t, frame)
        out += self._supervision(t, frame, seen)
        out += self._lone(t, frame, seen)
        for pid in [p for p, s in self.last_seen.items() if t - s > 60.0]:
            del self.last_seen[pid]  # bounded: people long gone
        return out

    def end(self, t: float, frame: int, aborted: bool = False) -> list[Event]:
        """The ticket's end: ticket_completed with its result (once)."""
        if self.ended_t is not None:
            return []
        self.ended_t = t
        result = self.result()
        result["aborted"] = aborted
        return [self._event("ticket_completed", t, frame, t, result=result)]

    def result(self) -> dict:
        """The steps done in order, the steps missed, the deviations counted."""
        st = self.ticket.steps
        done = [s.name for s, x in zip(st, self.steps, strict=True) if x.done_t is not None]
        missed = [
            s.name
            for s, x in zip(st, self.steps, strict=True)
            if x.done_t is None and not s.optional
        ]
        in_order = [
            s.name
            for s, x in zip(st, self.steps, strict=True)
            if x.done_t is not None and x.in_order and not x.failed
        ]
        counts = dict(self.deviation_counts)
        return {
            "steps": len(st),
            "done": done,
            "done_in_order": in_order,
            "missed": missed,
            "deviations": sum(counts.values()),
            "by_type": counts,
            "operator": self.operator,
            "supervisor": self.supervisor,
        }

    def progress(self) -> list[dict]:
        """Each step's state (the API's and the console's)."""
        out = []
        for s, x in zip(self.ticket.steps, self.steps, strict=True):
            state = "done" if x.done_t is not None else ("timed_out" if x.timed_out else "open")
            out.append(
                {
                    "name": s.name,
                    "position": s.position,
                    "target": s.target,
                    "optional": s.optional,
                    "state": state,
                    "done_t": x.done_t,
                    "onset_t": x.onset_t,
                    "by": x.by,
                    "in_order": x.in_order if x.done_t is not None else None,
                    "failed": x.failed or None,
                    "where": list(x.position) if x.position else None,
                }
            )
        return out

    # -- parts -----------------------------------------------------------------------------

    def _seen(self, people: People3D) -> Seen:
        seen = Seen()
        if not len(people):
            return seen
        real = ~np.asarray(people.predicted, bool)
        xy = floor_position(people.joints)
        heading = heading_deg(people.joints)
        for p in np.flatnonzero(real):
            if not np.isfinite(xy[p]).all():
                continue
            pid = int(people.ids[p])
            seen.xy[pid] = (float(xy[p, 0]), float(xy[p, 1]))
            seen.wrists[pid] = people.joints[p, [LEFT_WRIST, RIGHT_WRIST]]
            seen.heading[pid] = float(heading[p])
        return seen

    def _on_floor(self, zone: str, xy: tuple[float, float]) -> bool:
        k = self.index[zone]
        z = self.geometry.zones[k]
        mid = 0.5 * (z.z[0] + z.z[1])
        inside, _ = self.geometry.test(np.array([[[xy[0], xy[1], mid]]]), np.array([k]))
        return bool(inside[0, 0])

    def _hands_in(self, zone: str, wrists: np.ndarray) -> int:
        """How many of the two wrists are inside the zone."""
        k = self.index[zone]
        inside, _ = self.geometry.test(wrists[None], np.array([k]))
        return int(inside[0].sum())

    def _gone(self, pid: int | None, t: float) -> bool:
        """Whether a bound person has not been seen for REBIND_S."""
        return pid is not None and t - self.last_seen.get(pid, t) > REBIND_S

    def _bind(self, t: float, seen: Seen) -> None:
        tk = self.ticket
        if tk.operator == "auto" and self._gone(self.operator, t):
            self.operator = None
        if tk.supervisor == "auto" and self._gone(self.supervisor, t):
            self.supervisor = None
        if self.operator is None and tk.operator == "auto":
            self.operator = self._find_operator(seen)
        if (
            self.supervisor is None
            and tk.supervisor == "auto"
            and self.operator is not None
            and self.operator in seen.xy
        ):
            ox, oy = seen.xy[self.operator]
            near = [
                (math.hypot(x - ox, y - oy), pid)
                for pid, (x, y) in seen.xy.items()
                if pid != self.operator
            ]
            near = [n for n in near if n[0] <= tk.supervise_m]
            if near:
                self.supervisor = min(near)[1]

    def _find_operator(self, seen: Seen) -> int | None:
        steps = self.ticket.steps
        for s in steps:  # the first step's position first
            for pid in sorted(seen.xy):
                if self._on_floor(s.position, seen.xy[pid]):
                    return pid
        for s in steps:
            for pid in sorted(seen.wrists):
                if self._hands_in(s.target, seen.wrists[pid]):
                    return pid
        return None

    def _actions(self, t: float, frame: int, seen: Seen, postures: dict) -> list[Event]:
        op = self.operator
        if op is None or op not in seen.wrists:
            return []
        out: list[Event] = []
        for k, (s, x) in enumerate(zip(self.ticket.steps, self.steps, strict=True)):
            if x.done_t is not None:
                continue
            hands = self._hands_in(s.target, seen.wrists[op])
            acting = hands >= (2 if s.both_hands else 1)
            placed = self._on_floor(s.position, seen.xy[op])
            if not acting:
                if x.hold is not None and t - x.hold[1] > GAP_S + EPS:
                    x.hold = None
                continue
            if x.hold is None:
                x.hold = (t, t, placed)
            else:
                x.hold = (x.hold[0], t, x.hold[2] and placed)
            if t - x.hold[0] + EPS >= s.hold_s:
                out += self._done(k, s, x, t, frame, seen, postures)
        return out

    def _done(
        self, k: int, s: TicketStep, x: StepState, t: float, frame: int, seen: Seen, postures: dict
    ) -> list[Event]:
        op = self.operator
        assert x.hold is not None and op is not None  # _actions holds the step for an operator
        onset, _, placed = x.hold
        x.hold = None
        x.done_t, x.onset_t, x.by, x.position = t, onset, op, seen.xy[op]
        out: list[Event] = []
        earlier = [
            p.name
            for p, st in zip(self.ticket.steps[:k], self.steps[:k], strict=True)
            if st.done_t is None and not p.optional
        ]
        if earlier:
            x.in_order = False
            out.append(
                self._deviation("step_out_of_order", t, frame, onset, s, failed=",".join(earlier))
            )
        failed = [] if placed else ["position"]
        if s.facing_deg is not None:
            h = seen.heading.get(op, math.nan)
            off = abs((h - s.facing_deg + 180.0) % 360.0 - 180.0)
            if not math.isfinite(h) or off > s.tolerance_deg:
                failed.append("facing")
        if s.posture is not None:
            p = postures.get(op)
            if (None if p is None else p.posture) not in s.posture:
                failed.append("posture")
        if failed:
            x.failed = ",".join(failed)
            out.append(self._deviation("step_wrong_position", t, frame, onset, s, failed=x.failed))
        out.append(
            self._event(
                "step_done",
                t,
                frame,
                onset,
                step=s.name,
                zone=s.position,
                duration_s=t - onset,
                position=x.position,
            )
        )
        return out

    def _timeouts(self, t: float, frame: int) -> list[Event]:
        out: list[Event] = []
        since = self.started_t
        for s, x in zip(self.ticket.steps, self.steps, strict=True):
            due = since is not None and s.max_s is not None and t - since > s.max_s + EPS
            if since is not None and x.done_t is None and not x.timed_out and due:
                x.timed_out = True
                out.append(
                    self._deviation("step_timeout", t, frame, since, s, duration_s=t - since)
                )
            if x.done_t is not None:
                since = x.done_t
            elif not s.optional:
                since = None  # the next step's clock starts when this one is done
        return out

    def _supervision(self, t: float, frame: int, seen: Seen) -> list[Event]:
        tk = self.ticket
        op = self.operator
        if tk.supervisor is None or op is None or op not in seen.xy:
            return []
        sup = self.supervisor
        ok = False
        if sup is not None and sup in seen.xy:
            (ox, oy), (sx, sy) = seen.xy[op], seen.xy[sup]
            ok = math.hypot(sx - ox, sy - oy) <= tk.supervise_m + NEAR_EPS
        change = self.absent.step(not ok, t, tk.absent_s, 0.0)
        if change == "fell":
            return [self._event("supervisor_back", t, frame, t)]
        if change == "rose":
            since = self.absent.onset
            return [
                self._deviation("supervisor_absent", t, frame, since, None, duration_s=t - since)
            ]
        return []

    def _lone(self, t: float, frame: int, seen: Seen) -> list[Event]:
        tk = self.ticket
        if tk.lone_s is None:
            return []
        change = self.lone.step(len(seen.xy) == 1, t, tk.lone_s, 0.0)
        if change == "fell":
            return [self._event("lone_in_room_end", t, frame, t)]
        if change == "rose":
            since, pid = self.lone.onset, next(iter(seen.xy))
            return [
                self._deviation(
                    "lone_in_room", t, frame, since, None, person=pid, duration_s=t - since
                )
            ]
        return []

    # -- events ----------------------------------------------------------------------------

    def _deviation(
        self,
        type_: str,
        t: float,
        frame: int,
        onset: float,
        s: TicketStep | None,
        *,
        person: int | None = None,
        **more: Unpack[TicketFields],
    ) -> Event:
        """A deviation of step `s` (None: of the ticket as a whole), in its zone."""
        self.deviations.append({"type": type_, "t": t, "step": s.name if s else None})
        self.deviation_counts[type_] = self.deviation_counts.get(type_, 0) + 1
        if s is None:
            return self._event(type_, t, frame, onset, person=person, **more)
        more.setdefault("step", s.name)
        return self._event(type_, t, frame, onset, person=person, zone=s.position, **more)

    def _event(
        self,
        type_: str,
        t: float,
        frame: int,
        onset: float,
        *,
        person: int | None = None,
        zone: str | None = None,
        **more: Unpack[TicketFields],
    ) -> Event:
        """A ticket event about `person` (None: the operator, or none) in `zone` (None: none)."""
        if person is None:
            person = self.operator if self.operator is not None else -1
        return Event(
            t=t,
            frame=frame,
            person=int(person),
            zone=zone or "",
            kind=TICKET_KIND,
            type=type_,
            onset_t=float(onset),
            ticket=self.ticket.id,
            **more,
        )
