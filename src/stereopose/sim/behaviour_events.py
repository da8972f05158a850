"""Behaviour events of simulated scenes: the true ones (the rules on the true joints), a run's,
and their precision, recall and latency, per rule type.

An alarm of a run (person_down, lone_worker, work_position, immobile, overreach; never an
`_end`, `person_up` or an alarm closed lost) matches a true alarm of the same rule whose worker
is the one its track follows (sim.events.track_workers), raised within `window_s` of it; one to
one, closest first. Latency: a matched alarm's raise time minus the true one's. Falls are also
scored against the script: a scripted fall the true joints raise person_down for is found in
time when a run's person_down of that worker comes at most `within_s` after the scripted
landing plus down_s.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass

import numpy as np

from stereopose.behaviour.definitions import ALARM_TYPES, Rule, parse_rules
from stereopose.behaviour.rules import BehaviourMonitor
from stereopose.config import Config
from stereopose.sim.behaviour import BehaviourScene, site_rules
from stereopose.sim.detections import joints_in_view
from stereopose.sim.events import greedy_pairs
from stereopose.sim.scene import Scene
from stereopose.skeleton import NUM_JOINTS
from stereopose.types import Event, People3D


def scene_rules(bs: BehaviourScene, **kw: float) -> tuple[Rule, ...]:
    """The benchmark's rules for this scene (sim.behaviour.site_rules), parsed as a site
    file's."""
    return parse_rules(
        site_rules(bs.panels, down_s=bs.down_s, **kw), "simulated site", bs.site.zones
    )


def monitor_events(
    bs: BehaviourScene, rules: Sequence[Rule], people: Sequence[People3D]
) -> list[Event]:
    """Every event of the rules over `people` (one People3D per frame, in order)."""
    mon = BehaviourMonitor(rules, bs.site.zones, bs.scene.fps, Config().tracking.max_lost_s)
    out: list[Event] = []
    for p in people:
        events, _ = mon.step(p.frame / bs.scene.fps, p.frame, p)
        out.extend(events)
    return out


def truth_frames(scene: Scene) -> list[People3D]:
    """Every frame's workers as sim.scene.truth_people3d gives them (views counted for all
    frames at once)."""
    T, N = scene.present.shape
    C = len(scene.rig)
    views = joints_in_view(scene.truth, scene.rig).sum(1) if N else np.zeros((T, 0, NUM_JOINTS))
    out = []
    for t in range(T):
        idx = np.flatnonzero(scene.present[t])
        P = idx.shape[0]
        out.append(
            People3D(
                frame=t,
                joints=scene.truth[t, idx],
                conf=np.ones((P, NUM_JOINTS)),
                ids=scene.ids[idx],
                reprojection_px=np.zeros((P, NUM_JOINTS)),
                views=views[t, idx],
                detections=np.full((P, C), -1, dtype=np.int64),
            )
        )
    return out


def truth_events(bs: BehaviourScene, rules: Sequence[Rule]) -> list[Event]:
    """The events the rules raise on the true joints (person = worker id)."""
    return monitor_events(bs, rules, truth_frames(bs.scene))


@dataclass(frozen=True)
class AlarmMetrics:
    """A run's alarms of one type against the true ones (see the module)."""

    type: str
    true: int
    predicted: int
    matched: int
    precision: float
    recall: float
    latency_mean_s: float
    latency_max_s: float

    def as_dict(self) -> dict:
        return asdict(self)


def _alarms(events: Sequence[Event], type_: str) -> list[Event]:
    return [e for e in events if e.type == type_ and not e.lost]


def evaluate_alarms(
    events: Sequence[Event],
    truth: Sequence[Event],
    workers: dict[int, int],
    type_: str,
    window_s: float = 2.0,
) -> AlarmMetrics:
    """Alarms of `type_` of a run (events; person = track id) against the truth's (person =
    worker id); workers: track id -> worker id."""
    if type_ not in ALARM_TYPES:
        raise ValueError(f"{type_!r} is not an alarm type; expected one of {sorted(ALARM_TYPES)}")
    pred, true = _alarms(events, type_), _alarms(truth, type_)
    pairs = []
    for i, e in enumerate(pred):
        w = workers.get(e.person)
        for j, g in enumerate(true):
            gap = abs(e.t - g.t)
            if g.person == w and g.rule == e.rule and gap <= window_s:
                pairs.append((gap, i, j))
    latency = [pred[i].t - true[j].t for i, j in greedy_pairs(pairs)]
    m = len(latency)
    lat = np.array(latency) if latency else np.array([np.nan])
    return AlarmMetrics(
        type=type_,
        true=len(true),
        predicted=len(pred),
        matched=m,
        precision=m / len(pred) if pred else float("nan"),
        recall=m / len(true) if true else float("nan"),
        latency_mean_s=float(np.mean(lat)),
        latency_max_s=float(np.max(lat)),
    )


@dataclass(frozen=True)
class FallResult:
    """One scripted fall: whether the true joints raise person_down for it (due; a fall that
    lands less than down_s + within_s before the scene ends is never due: the run has no time
    to raise it), and the run's first person_down of that worker after it: its delay after
    landing + down_s (NaN: none within the fall's time down plus 10 s)."""

    worker: int
    t_floor: float
    down_for_s: float
    due: bool
    delay_s: float

    def as_dict(self) -> dict:
        return asdict(self)


def score_falls(
    bs: BehaviourScene,
    events: Sequence[Event],
    truth: Sequence[Event],
    workers: dict[int, int],
    rule: str = "man_down",
    within_s: float = 2.0,
) -> list[FallResult]:
    """Each scripted fall of the scene against the true and the run's person_down of `rule`."""
    down_s = bs.down_s
    out = []
    end = bs.duration_s
    for f in bs.falls:
        horizon = f.t_floor + f.down_for(end) + 10.0
        due = f.t_floor + down_s + within_s <= end and any(
            g.rule == rule and g.person == f.worker and f.t0 - 1.0 <= g.onset_t <= horizon
            for g in _alarms(truth, "person_down")
        )
        raised = [
            e.t
            for e in _alarms(events, "person_down")
            if e.rule == rule and workers.get(e.person) == f.worker and f.t0 - 1.0 <= e.t <= horizon
        ]
        delay = min(raised) - (f.t_floor + down_s) if raised else float("nan")
        out.append(FallResult(f.worker, f.t_floor, f.down_for(end), due, float(delay)))
    return out
