"""person_down: a fall seen (a fast drop of the trunk to the floor, then lying), a person
found lying for `lying_s` without a fall seen, and the fall handed to the new id of a track
broken by it (a track that dropped fast and vanished, a new one low on the floor within
HANDOVER_M of it within HANDOVER_S). The alarm is raised `down_s` after the fall even while
the body is hidden, and ends (`person_up`) once the person is upright for `up_s`."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TypedDict, Unpack

from stereopose.behaviour.definitions import BEHAVIOUR_KIND, PersonDownRule, Rule
from stereopose.behaviour.state import EPS, DownState, Seen, Tracked
from stereopose.types import Event

# a track that dropped fast and vanished, and a new one on the floor within HANDOVER_M of it
# within HANDOVER_S: the same body, its id changed by the fall
HANDOVER_S = 1.5
HANDOVER_M = 1.5


class BehaviourFields(TypedDict, total=False):
    """What a behaviour event may carry beyond its rule, person and times (types.Event)."""

    zone: str | None  # the zone it happened in (None: none)
    posture: str | None  # default: the person's posture now
    joint: str | None
    duration_s: float | None
    lost: bool
    nearest_m: float | None
    facing_deg: float | None
    failed: str | None
    height_m: float | None
    speed_m_s: float | None


def rule_event(
    rule: Rule,
    pid: int,
    person: Tracked,
    type_: str,
    t: float,
    frame: int,
    onset_t: float,
    **more: Unpack[BehaviourFields],
) -> Event:
    """A behaviour event of `rule` about `person` (their posture unless given, and their floor
    position)."""
    posture = person.posture.posture if person.posture is not None else None
    return Event(
        t=t,
        frame=frame,
        person=pid,
        zone=more.get("zone") or "",
        kind=BEHAVIOUR_KIND,
        type=type_,
        onset_t=float(onset_t),
        position=person.position,
        rule=rule.name,
        posture=more.get("posture", posture),
        joint=more.get("joint"),
        duration_s=more.get("duration_s"),
        lost=more.get("lost", False),
        nearest_m=more.get("nearest_m"),
        facing_deg=more.get("facing_deg"),
        failed=more.get("failed"),
        height_m=more.get("height_m"),
        speed_m_s=more.get("speed_m_s"),
    )


class Falls:
    """The person_down rules' memory beside the people's states. people: the monitor's
    tracked people (shared, by id)."""

    def __init__(self, people: dict[int, Tracked], rules: Sequence[Rule]) -> None:
        self.people = people
        downs = [r.fall_speed_m_s for r in rules if isinstance(r, PersonDownRule)]
        self.fall_speed = min(downs) if downs else None
        self.drops: dict[int, tuple[float, float, float, float]] = {}  # pid: t, x, y, m/s
        self.seen_now: set[int] = set()

    def note_drops(self, t: float, seen: list) -> None:
        """Who dropped fast lately, and where (for a fall whose track breaks: _handover)."""
        if not self.fall_speed:
            return
        for pid, person in ((pid, person) for _, pid, person in seen if pid in self.seen_now):
            pos = person.posture
            if pos is not None and person.position is not None and pos.drop_m_s >= self.fall_speed:
                self.drops[pid] = (t, *person.position, pos.drop_m_s)
        for pid in [p for p, d in self.drops.items() if t - d[0] > HANDOVER_S + EPS]:
            del self.drops[pid]

    def person_down(self, rule: PersonDownRule, c: Seen) -> list[Event]:
        person, t = c.person, c.base["t"]
        st = person.down.setdefault(rule.name, DownState())
        pos = person.posture
        if pos is None or (c.people.predicted is not None and c.people.predicted[c.p]):
            return self.down_timer(rule, c.pid, person, t, c.base["frame"])
        out: list[Event] = []
        if st.fall_t is None:
            fast = math.isfinite(pos.drop_m_s) and pos.drop_m_s >= rule.fall_speed_m_s
            low = math.isfinite(pos.trunk_m) and pos.trunk_m - pos.ground_m <= rule.floor_m
            if fast and low:
                st.fall_t, st.speed = t, pos.drop_m_s
            elif low and t - person.first_seen <= HANDOVER_S + EPS:
                st = self._handover(rule, c.pid, person, t) or st
            if st.fall_t is None and rule.lying_s is not None:
                return self.found_lying(rule, c, st)
        if st.fall_t is None:
            return out
        if not st.down:
            if pos.posture == "lying":
                st.down = True
            elif t - st.fall_t > rule.settle_s + EPS:  # not a fall: they never lay
                person.down[rule.name] = DownState()
                return out
        if st.down:
            change = st.up.step(pos.upright, t, rule.up_s, 0.0)
            if change == "rose":  # up again
                if st.raised:
                    out.append(
                        rule_event(
                            rule,
                            c.pid,
                            person,
                            "person_up",
                            t,
                            c.base["frame"],
                            onset_t=st.up.onset,
                            duration_s=float(st.up.onset - st.fall_t),
                        )
                    )
                person.down[rule.name] = DownState()
                return out
        out.extend(self.down_timer(rule, c.pid, person, t, c.base["frame"]))
        return out

    def _handover(
        self, rule: PersonDownRule, pid: int, person: Tracked, t: float
    ) -> DownState | None:
        """A person first seen on the floor where another track, not seen now, had just
        dropped fast: the tracker lost the body as it fell and gave it a new id. The fall (and
        the old track's down state, if it had one) goes to the new id."""
        if person.position is None:
            return None
        x, y = person.position
        best = None
        for other, (t0, ox, oy, speed) in self.drops.items():
            if other == pid or other in self.seen_now or t - t0 > HANDOVER_S + EPS:
                continue
            d = math.hypot(ox - x, oy - y)
            if d <= HANDOVER_M and speed >= rule.fall_speed_m_s and (best is None or d < best[0]):
                best = (d, other, t0, speed)
        if best is None:
            return None
        _, other, t0, speed = best
        old = self.people.get(other)
        st = old.down.pop(rule.name, None) if old is not None else None
        if st is None or st.fall_t is None:
            st = DownState(fall_t=t0, speed=speed)
        person.down[rule.name] = st
        return st

    def found_lying(self, rule: PersonDownRule, c: Seen, st: DownState) -> list[Event]:
        """lying_s: a person lying that long without a fall seen (it happened out of view, or
        before the start) is down as well."""
        t = c.base["t"]
        lying = c.person.posture is not None and c.person.posture.posture == "lying"
        assert rule.lying_s is not None  # asked only of a rule with lying_s
        if st.lying.step(lying, t, rule.lying_s, 0.0) != "rose":
            return []
        fall_t = st.lying.began
        assert fall_t is not None  # it rose: since then
        st.fall_t, st.down, st.raised = fall_t, True, True
        return [
            rule_event(
                rule,
                c.pid,
                c.person,
                "person_down",
                t,
                c.base["frame"],
                onset_t=fall_t,
                duration_s=float(t - fall_t),
                posture="lying",
            )
        ]

    def down_timer(
        self, rule: PersonDownRule, pid: int, person: Tracked, t: float, frame: int
    ) -> list[Event]:
        st = person.down.get(rule.name)
        if st is None or not st.down or st.raised or st.fall_t is None:
            return []
        if t - st.fall_t < rule.down_s - EPS:
            return []
        st.raised = True
        person.detail[rule.name] = {}
        return [
            rule_event(
                rule,
                pid,
                person,
                "person_down",
                t,
                frame,
                onset_t=st.fall_t,
                duration_s=float(t - st.fall_t),
                speed_m_s=float(st.speed),
                posture="lying",
            )
        ]
