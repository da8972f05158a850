"""Zones on simulated scenes, their true events, and event matching."""

from __future__ import annotations

import dataclasses

import numpy as np

from stereopose.sim import simulate, truth_people3d
from stereopose.sim.events import evaluate_events, make_zones, track_workers, truth_events


def test_zones_are_entered_and_truth_matches_itself() -> None:
    scene = simulate(difficulty="easy", num_frames=250, seed=0)
    site = make_zones(scene, np.random.default_rng(7))
    assert [z.kind for z in site.zones] == ["energized", "restricted", "work_area", "energized"]
    truth = truth_events(scene, site)
    assert any(e.type == "enter" for e in truth)
    preds = [truth_people3d(scene, t) for t in range(scene.num_frames)]
    workers = track_workers(preds, scene)
    assert workers == {int(i): int(i) for i in scene.ids}
    m = evaluate_events(truth, truth, workers)
    assert m.precision == m.recall == 1.0 and m.matched == m.true
    # every enter opens a zone that an exit later closes, or stays open at the end
    for e in truth:
        assert e.t >= e.onset_t


def test_event_matching_counts_misses_false_and_late_events() -> None:
    scene = simulate(difficulty="easy", num_frames=250, seed=0)
    site = make_zones(scene, np.random.default_rng(7))
    truth = [e for e in truth_events(scene, site) if e.type in ("enter", "exit")]
    workers = {int(i): int(i) for i in scene.ids}
    shifted = [dataclasses.replace(e, onset_t=e.onset_t + 1.0, t=e.t + 1.0) for e in truth[:1]]
    wrong_zone = [dataclasses.replace(e, zone="nowhere") for e in truth[1:2]]
    run = shifted + wrong_zone + truth[2:]
    m = evaluate_events(run, truth, workers)
    assert m.matched == len(truth) - 2 and m.predicted == len(truth)
    assert m.recall == (len(truth) - 2) / len(truth)
    assert m.within_window == 1.0 and m.latency_max_s <= 0.5
