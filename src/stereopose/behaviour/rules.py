"""The behaviour rules over tracked people, frame by frame: person_down, lone_worker,
work_position, immobile, overreach (their definitions: behaviour.definitions).

`BehaviourMonitor.step(t, frame, people)` once per frame gives the frame's events and each
person's posture (behaviour.posture). Conditions are debounced like the zone events: a
condition must hold for its rule's delay before its event is raised (online, at the frame the
delay completes, with `onset_t` the time the condition began), and an alarm ends (`<type>_end`,
or `person_up`) once its condition has been false for the rule's exit delay. A person not seen
at a frame keeps their state (and counts as company for lone_worker at their last place) until
their track ends (`lost_s`, the tracker's max_lost_s): then their open alarms end, marked lost.
A person down stays down while unseen: the alarm is raised on time even if the body is hidden.
A fall that breaks the track (the body gets a new id on the floor) is handed to the new id:
a track that dropped fast and vanished, a new one low on the floor within HANDOVER_M of it
within HANDOVER_S.

Every event has kind "behaviour", the rule's name in `rule`, the person's posture and floor
position, and what explains it (behaviour events in types.Event).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from stereopose.behaviour.definitions import (
    ImmobileRule,
    LoneWorkerRule,
    OverreachRule,
    PersonDownRule,
    Rule,
    WorkPositionRule,
    parse_rules,
)
from stereopose.behaviour.falls import HANDOVER_S, Falls, rule_event
from stereopose.behaviour.posture import (
    DEFAULT_SETTINGS,
    Posture,
    PostureSettings,
    PostureTracker,
)
from stereopose.behaviour.state import (
    EPS,
    Latch,
    Seen,
    StillState,
    Tracked,
    angle_diff,
    on_floor_of,
)
from stereopose.skeleton import JOINTS, LEFT_WRIST, RIGHT_WRIST, floor_position, heading_deg
from stereopose.types import Event, People3D
from stereopose.zones import Zone, ZoneGeometry

__all__ = ["HANDOVER_S", "BehaviourMonitor", "Rule", "parse_rules"]

_WRISTS = (LEFT_WRIST, RIGHT_WRIST)


class BehaviourMonitor:
    """Turns tracked people into behaviour events and postures (see the module).

    rules: parsed rules (behaviour.definitions.parse_rules); zones: the site's zones the rules
    name; fps: the frame rate; max_lost_s: a person unseen this long has left (their track
    ended); settings: the posture thresholds.
    """

    def __init__(
        self,
        rules: Sequence[Rule],
        zones: Sequence[Zone],
        fps: float,
        max_lost_s: float,
        settings: PostureSettings = DEFAULT_SETTINGS,
    ) -> None:
        self.rules = tuple(rules)
        self.zones = tuple(zones)
        self.fps = float(fps)
        self.lost_s = float(max_lost_s)
        self.tracker = PostureTracker(fps, settings, max_lost_s)
        self.geometry = ZoneGeometry(self.zones) if self.zones else None
        self._zone_index = {z.name: k for k, z in enumerate(self.zones)}
        energized = [k for k, z in enumerate(self.zones) if z.kind == "energized"]
        self._energized = {
            r.name: [self._zone_index[n] for n in r.energized] or energized
            for r in self.rules
            if isinstance(r, WorkPositionRule)
        }
        self.people: dict[int, Tracked] = {}
        self.falls = Falls(self.people, self.rules)

    def step(
        self, t: float, frame: int, people: People3D
    ) -> tuple[list[Event], dict[int, Posture]]:
        """The events raised at this frame and each person's posture by id."""
        postures = self.tracker.update(t, people)
        events: list[Event] = []
        P = len(people)
        predicted = np.zeros(P, bool) if people.predicted is None else people.predicted
        pos = floor_position(people.joints) if P else np.zeros((0, 2))
        heading = heading_deg(people.joints) if P else np.zeros(0)
        inside = nearest = None
        if P and self.geometry is not None:
            inside, dist = self.geometry.distance(people.joints.reshape(-1, 3))
            inside = inside.reshape(P, -1, len(self.zones))  # (P, 17, Z)
            nearest = dist.reshape(P, -1, len(self.zones)).min(axis=1)  # (P, Z)
        seen = []
        for p in range(P):
            pid = int(people.ids[p])
            person = self.people.get(pid)
            if person is None:
                person = self.people[pid] = Tracked(last_seen=t, first_seen=t)
            if not predicted[p]:
                person.last_seen = t
            xy = pos[p]
            person.position = (float(xy[0]), float(xy[1])) if np.isfinite(xy).all() else None
            person.posture = postures.get(pid)
            seen.append((p, pid, person))
        self.falls.seen_now = {pid for p, pid, _ in seen if not predicted[p]}
        self.falls.note_drops(t, seen)
        base = dict(frame=frame, t=t)
        for rule in self.rules:
            for p, pid, person in seen:
                if predicted[p] and not isinstance(rule, PersonDownRule):
                    continue  # unseen: the state is kept as it was
                ctx = Seen(p, pid, person, people, inside, nearest, float(heading[p]), base)
                events.extend(self._apply(rule, ctx))
            if isinstance(rule, PersonDownRule):  # time goes on for the unseen down
                shown = {pid for _, pid, _ in seen}
                for pid, person in self.people.items():
                    if pid not in shown:
                        events.extend(self.falls.down_timer(rule, pid, person, t, frame))
        events.extend(self._lost(t, frame))
        return events, postures

    def _apply(self, rule: Rule, ctx: Seen) -> list[Event]:
        if isinstance(rule, PersonDownRule):
            return self.falls.person_down(rule, ctx)
        if isinstance(rule, LoneWorkerRule):
            return self._lone_worker(rule, ctx)
        if isinstance(rule, WorkPositionRule):
            return self._work_position(rule, ctx)
        if isinstance(rule, ImmobileRule):
            return self._immobile(rule, ctx)
        return self._overreach(rule, ctx)

    # -- lone_worker -----------------------------------------------------------------------

    def _lone_worker(self, rule: LoneWorkerRule, c: Seen) -> list[Event]:
        t, person = c.base["t"], c.person
        zone, near = self._nearest_zone(rule.zones, c)
        at_risk = zone is not None and near <= rule.approach_m + EPS
        nearest = self._nearest(c.pid, person)
        alone = not (nearest <= rule.buddy_m + EPS)
        latch = person.latches.setdefault(rule.name, Latch())
        change = latch.step(at_risk and alone, t, rule.lone_s, rule.exit_s)
        nearest_m = None if math.isinf(nearest) or math.isnan(nearest) else float(nearest)
        if change == "rose":
            person.detail[rule.name] = {"zone": zone}
            return [
                rule_event(
                    rule,
                    c.pid,
                    person,
                    "lone_worker",
                    t,
                    c.base["frame"],
                    onset_t=latch.onset,
                    zone=zone,
                    nearest_m=nearest_m,
                    duration_s=float(t - latch.began),
                )
            ]
        if change == "fell":
            began = latch.began if latch.began is not None else t
            return [
                rule_event(
                    rule,
                    c.pid,
                    person,
                    "lone_worker_end",
                    t,
                    c.base["frame"],
                    onset_t=latch.onset,
                    zone=person.detail.pop(rule.name, {}).get("zone") or "",
                    nearest_m=nearest_m,
                    duration_s=float(t - began),
                )
            ]
        return []

    def _nearest_zone(self, names: Sequence[str], c: Seen) -> tuple[str | None, float]:
        """The zone of `names` nearest to the person's joints, and its distance (0 inside)."""
        zone, near = None, math.inf
        if c.nearest is not None:
            for name in names:
                d = float(c.nearest[c.p, self._zone_index[name]])
                if d < near:
                    zone, near = name, d
        return zone, near

    def _nearest(self, pid: int, person: Tracked) -> float:
        """Floor distance to the nearest other person (seen now or still tracked)."""
        if person.position is None:
            return math.nan
        x, y = person.position
        best = math.inf
        for other_id, other in self.people.items():
            if other_id != pid and other.position is not None:
                best = min(best, math.hypot(other.position[0] - x, other.position[1] - y))
        return best

    # -- work_position ---------------------------------------------------------------------

    def _work_position(self, rule: WorkPositionRule, c: Seen) -> list[Event]:
        t, person = c.base["t"], c.person
        hand_zone, hand = None, None
        if c.inside is not None:
            for k in self._energized[rule.name]:
                for j in _WRISTS:
                    if c.inside[c.p, j, k]:
                        hand_zone, hand = self.zones[k].name, j
                        break
                if hand_zone is not None:
                    break
        failed: list[str] = []
        facing = float(c.heading) if math.isfinite(c.heading) else None
        if hand_zone is not None:
            k = self._zone_index[rule.zone]
            if person.position is None or not on_floor_of(self.geometry, k, person.position):
                failed.append("position")
            if facing is None or abs(angle_diff(facing, rule.facing_deg)) > rule.tolerance_deg:
                failed.append("facing")
            posture = person.posture.posture if person.posture is not None else None
            if rule.postures is not None and posture not in rule.postures:
                failed.append("posture")
        latch = person.latches.setdefault(rule.name, Latch())
        change = latch.step(bool(failed), t, rule.enter_s, rule.exit_s)
        if change == "rose":
            person.detail[rule.name] = {"zone": hand_zone}
            return [
                rule_event(
                    rule,
                    c.pid,
                    person,
                    "work_position",
                    t,
                    c.base["frame"],
                    onset_t=latch.onset,
                    zone=hand_zone,
                    joint=None if hand is None else JOINTS[hand],
                    failed=",".join(failed),
                    facing_deg=facing,
                )
            ]
        if change == "fell":
            began = latch.began if latch.began is not None else t
            return [
                rule_event(
                    rule,
                    c.pid,
                    person,
                    "work_position_end",
                    t,
                    c.base["frame"],
                    onset_t=latch.onset,
                    zone=person.detail.pop(rule.name, {}).get("zone") or "",
                    facing_deg=facing,
                    duration_s=float(t - began),
                )
            ]
        return []

    # -- immobile --------------------------------------------------------------------------

    def _immobile(self, rule: ImmobileRule, c: Seen) -> list[Event]:
        t, person = c.base["t"], c.person
        J = c.people.joints[c.p]
        ok = np.isfinite(J).all(-1)
        st = person.still.get(rule.name)
        if st is None:
            st = person.still[rule.name] = StillState(
                np.where(ok[:, None], J, np.nan), ok.astype(np.int64), t
            )
            return []
        both = ok & (st.count > 0)
        moved = (
            bool(both.any())
            and float(np.max(np.linalg.norm(J[both] - st.mean[both], axis=-1))) > rule.still_m
        )
        out: list[Event] = []
        if moved:
            moved_since = t if st.moved_since is None else st.moved_since
            st.moved_since = moved_since
            if t - moved_since >= rule.move_s - EPS:
                if st.raised:
                    out.append(
                        rule_event(
                            rule,
                            c.pid,
                            person,
                            "immobile_end",
                            t,
                            c.base["frame"],
                            onset_t=moved_since,
                            duration_s=float(moved_since - st.since),
                        )
                    )
                person.still[rule.name] = StillState(
                    np.where(ok[:, None], J, np.nan), ok.astype(np.int64), t
                )
            return out
        st.moved_since = None
        # the running mean of each joint over the still period (joints seen late join it)
        n = st.count[ok] + 1
        st.mean[ok] = np.where(
            (st.count[ok] > 0)[:, None], st.mean[ok] + (J[ok] - st.mean[ok]) / n[:, None], J[ok]
        )
        st.count[ok] = n
        if not st.raised and t - st.since >= rule.immobile_s - EPS:
            st.raised = True
            out.append(
                rule_event(
                    rule,
                    c.pid,
                    person,
                    "immobile",
                    t,
                    c.base["frame"],
                    onset_t=st.since,
                    duration_s=float(t - st.since),
                )
            )
        return out

    # -- overreach -------------------------------------------------------------------------

    def _overreach(self, rule: OverreachRule, c: Seen) -> list[Event]:
        t, person = c.base["t"], c.person
        z = c.people.joints[c.p, list(rule.joints), 2].tolist()
        known = [(h, k) for k, h in enumerate(z) if math.isfinite(h)]
        height, top = max(known) if known else (math.nan, -1)
        raw = top >= 0 and height > rule.max_height_m
        zone = None
        if rule.zones:  # only near these zones
            zone, near = self._nearest_zone(rule.zones, c)
            raw = raw and near <= rule.approach_m + EPS
        latch = person.latches.setdefault(rule.name, Latch())
        change = latch.step(raw, t, rule.enter_s, rule.exit_s)
        if change == "rose":
            person.detail[rule.name] = {"zone": zone}
            return [
                rule_event(
                    rule,
                    c.pid,
                    person,
                    "overreach",
                    t,
                    c.base["frame"],
                    onset_t=latch.onset,
                    joint=JOINTS[rule.joints[top]],
                    height_m=height,
                    zone=zone,
                )
            ]
        if change == "fell":
            began = latch.began if latch.began is not None else t
            return [
                rule_event(
                    rule,
                    c.pid,
                    person,
                    "overreach_end",
                    t,
                    c.base["frame"],
                    onset_t=latch.onset,
                    duration_s=float(t - began),
                    zone=person.detail.pop(rule.name, {}).get("zone"),
                )
            ]
        return []

    # -- tracks that ended -----------------------------------------------------------------

    def _lost(self, t: float, frame: int) -> list[Event]:
        """End events, marked lost, for the open alarms of people whose track ended."""
        gone = [pid for pid, p in self.people.items() if t - p.last_seen > self.lost_s + EPS]
        out: list[Event] = []
        ends = {
            "lone_worker": "lone_worker_end",
            "work_position": "work_position_end",
            "overreach": "overreach_end",
        }
        for pid in gone:
            person = self.people.pop(pid)
            for rule in self.rules:
                latch = person.latches.get(rule.name)
                end = ends.get(rule.type)
                if end and latch is not None and latch.state:
                    detail = person.detail.get(rule.name, {})
                    out.append(
                        rule_event(
                            rule,
                            pid,
                            person,
                            end,
                            t,
                            frame,
                            onset_t=person.last_seen,
                            zone=detail.get("zone") or "",
                            lost=True,
                            duration_s=float(person.last_seen - (latch.began or t)),
                        )
                    )
                st = person.still.get(rule.name)
                if isinstance(rule, ImmobileRule) and st is not None and st.raised:
                    out.append(
                        rule_event(
                            rule,
                            pid,
                            person,
                            "immobile_end",
                            t,
                            frame,
                            onset_t=person.last_seen,
                            lost=True,
                            duration_s=float(person.last_seen - st.since),
                        )
                    )
        return out
