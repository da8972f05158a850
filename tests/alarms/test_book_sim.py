"""A simulated substation: workers reaching into energized panels again and again, their
true joints (with noise) through the fence, the events into the book: at most one incident
per person-zone episode, and every episode with an alarm has its incident."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from stereopose.alarms import AlarmSettings, IncidentBook, raises
from stereopose.fence import FenceMonitor, ZoneGeometry
from stereopose.sim.behaviour import simulate_behaviour
from stereopose.sim.behaviour_events import truth_frames


@pytest.fixture(scope="module")
def work():
    bs = simulate_behaviour("work", seed=1, difficulty="easy", duration_s=120.0)
    return bs, truth_frames(bs.scene)


def episodes(bs, frames, rearm_s: float) -> dict[tuple[str, int], int]:
    """Per (zone, person): the periods a joint is inside the zone or within its margin,
    those less than rearm_s apart taken as one."""
    geo = ZoneGeometry(bs.site.zones)
    margin = np.array([z.margin_m for z in bs.site.zones])
    seen: dict[tuple[str, int], list[float]] = {}
    for p in frames:
        for q in range(len(p.ids)):
            inside, dist = geo.distance(p.joints[q])
            for k in np.flatnonzero((inside | (dist <= margin)).any(0)):
                seen.setdefault((bs.site.zones[k].name, int(p.ids[q])), []).append(p.frame)
    fps = bs.scene.fps
    return {key: 1 + int((np.diff(f) / fps > rearm_s).sum()) for key, f in seen.items()}


@pytest.mark.parametrize("noise_m", [0.0, 0.05])
@pytest.mark.parametrize("with_holding", [True, False])
def test_at_most_one_incident_per_person_zone_episode(work, noise_m, with_holding) -> None:
    bs, frames = work
    rng = np.random.default_rng(3)
    fps = bs.scene.fps
    mon = FenceMonitor(bs.site, fps)
    book = IncidentBook(AlarmSettings.from_site(bs.site))
    alarms: dict[tuple[str, int], int] = {}
    incidents: dict[tuple[str, int], set[int]] = {}
    notified = 0
    noisy = []
    for p in frames:
        p = dataclasses.replace(p, joints=p.joints + rng.normal(0.0, noise_m, p.joints.shape))
        noisy.append(p)
        events = mon.update(p)
        holding = None
        if with_holding:  # the fence's own state: inside or within the margin, debounced
            rows, ks = np.nonzero(mon.inside.state | mon.near.state)
            holding = {(mon.zones[k].name, int(mon.ids[r])) for r, k in zip(rows, ks, strict=True)}
        up = book.update(events, p.frame / fps, holding=holding)
        notified += len(up.notifications)
        for e, i in zip(events, up.incidents, strict=True):
            if raises(e):
                alarms[(e.zone, e.person)] = alarms.get((e.zone, e.person), 0) + 1
                incidents.setdefault((e.zone, e.person), set()).add(i)
    eps = episodes(bs, noisy, 30.0)
    per_pair = {key: len(ids) for key, ids in incidents.items()}
    assert per_pair and all(1 <= n <= eps[key] for key, n in per_pair.items()), (per_pair, eps)
    assert notified == sum(per_pair.values())
    # the scene does reach again and again: one alarm per event would be several per episode
    assert any(alarms[key] > 2 * eps[key] for key in per_pair), (alarms, eps)
