"""Zones for simulated scenes, their ground-truth events, and event precision, recall and
latency of a run against them."""

from __future__ import annotations

from collections import Counter
from collections.abc import Sequence
from dataclasses import asdict, dataclass

import numpy as np

from stereopose.fence import FenceMonitor, Site, Zone
from stereopose.sim.metrics import match_people
from stereopose.sim.scene import Scene, truth_people3d
from stereopose.types import Event, People3D


def make_zones(scene: Scene, rng: np.random.Generator, count: int = 4) -> Site:
    """`count` rectangular zones over the floor where workers walk: kinds in turn energized,
    restricted, work_area; 1-3 m wide, height band 0-2.5 m, energized ones with a 0.5 m
    approach margin."""
    W, D = scene.room[:2]
    zones = []
    kinds = ("energized", "restricted", "work_area")
    for k in range(count):
        w, d = rng.uniform(1.0, 3.0, 2)
        x0, y0 = rng.uniform([0.8, 0.8], [W - 0.8 - w, D - 0.8 - d])
        kind = kinds[k % 3]
        zones.append(
            Zone(
                name=f"{kind}_{k}",
                kind=kind,
                polygon=np.array([[x0, y0], [x0 + w, y0], [x0 + w, y0 + d], [x0, y0 + d]]),
                z=(0.0, 2.5),
                margin_m=0.5 if kind == "energized" else 0.0,
            )
        )
    return Site(tuple(zones), scene.fps)


def truth_events(scene: Scene, site: Site) -> list[Event]:
    """The events the same rules raise on the ground truth (person = worker id)."""
    mon = FenceMonitor(site, scene.fps)
    out: list[Event] = []
    for t in range(scene.num_frames):
        out.extend(mon.update(truth_people3d(scene, t)))
    return out


@dataclass(frozen=True)
class EventMetrics:
    """Enter/exit events of a run against the truth's.

    A run's event matches a true one of the same zone and type whose worker is the one its
    track follows (the worker it matched most often), with onsets within `window_s`; one to
    one, closest first. latency: raise time of a matched event minus the true onset (the first
    frame the worker was truly inside, or truly outside for an exit).
    """

    true: int
    predicted: int
    matched: int
    precision: float
    recall: float
    latency_mean_s: float
    latency_max_s: float
    within_window: float  # fraction of matched events raised within window_s of the true onset

    def as_dict(self) -> dict:
        return asdict(self)


def track_workers(predictions: Sequence[People3D], scene: Scene) -> dict[int, int]:
    """Track id -> worker id it matched most often."""
    votes: dict[int, Counter] = {}
    for pred in predictions:
        idx = np.flatnonzero(scene.present[pred.frame])
        for p, n in match_people(pred.joints, scene.truth[pred.frame, idx]):
            votes.setdefault(int(pred.ids[p]), Counter())[int(scene.ids[idx[n]])] += 1
    return {i: c.most_common(1)[0][0] for i, c in votes.items()}


def greedy_pairs(candidates: Sequence[tuple[float, int, int]]) -> list[tuple[int, int]]:
    """One-to-one pairs (predicted i, true j) from candidates (gap, i, j), the smallest gaps
    first: each predicted and each true event in one pair at most."""
    used_p: set[int] = set()
    used_t: set[int] = set()
    pairs = []
    for _, i, j in sorted(candidates):
        if i in used_p or j in used_t:
            continue
        used_p.add(i)
        used_t.add(j)
        pairs.append((i, j))
    return pairs


def evaluate_events(
    events: Sequence[Event],
    truth: Sequence[Event],
    workers: dict[int, int],
    types: tuple[str, ...] = ("enter", "exit"),
    window_s: float = 0.5,
) -> EventMetrics:
    pred = [e for e in events if e.type in types and not e.lost]
    true = [e for e in truth if e.type in types and not e.lost]
    pairs = []
    for i, e in enumerate(pred):
        w = workers.get(e.person)
        for j, g in enumerate(true):
            if g.person == w and g.zone == e.zone and g.type == e.type:
                gap = abs(e.onset_t - g.onset_t)
                if gap <= window_s:
                    pairs.append((gap, i, j))
    latency = [pred[i].t - true[j].onset_t for i, j in greedy_pairs(pairs)]
    m = len(latency)
    lat = np.array(latency) if latency else np.array([np.nan])
    return EventMetrics(
        true=len(true),
        predicted=len(pred),
        matched=m,
        precision=m / len(pred) if pred else float("nan"),
        recall=m / len(true) if true else float("nan"),
        latency_mean_s=float(np.mean(lat)),
        latency_max_s=float(np.max(lat)),
        within_window=float(np.mean(np.abs(lat) <= window_s)) if latency else float("nan"),
    )
