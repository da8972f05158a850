"""Simulated workers who kneel, sit, fall and get up; their true behaviour events; the lying
body through the real 3D back end; alarm matching."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from stereopose.behaviour.posture import PostureTracker, classify
from stereopose.config import Config
from stereopose.pipeline.stage3d import Stage3D
from stereopose.sim.behaviour import simulate_behaviour
from stereopose.sim.behaviour_events import (
    evaluate_alarms,
    monitor_events,
    scene_rules,
    score_falls,
    truth_events,
    truth_frames,
)
from stereopose.sim.events import track_workers
from stereopose.sim.metrics import match_people
from stereopose.sim.postures import SHAPES, Act, Actor, body, hips_z
from stereopose.skeleton import LIMBS

FPS = 25.0


@pytest.fixture(scope="module")
def work():
    """A work scene and its true events."""
    bs = simulate_behaviour("work", seed=1, difficulty="easy", duration_s=120.0)
    return bs, truth_events(bs, scene_rules(bs))


def _one(shape: str, height: float, fall_dir: float = 0.0, heading: float = 0.3) -> np.ndarray:
    signals = {
        "heading": np.array([heading]),
        "shape": SHAPES[shape][None],
        "fall_dir": np.array([fall_dir]),
    }
    return body(height, np.array([[5.0, 4.0]]), signals)[0]


@pytest.mark.parametrize(
    ("shape", "posture"),
    [
        ("stand", "standing"),
        ("bend", "bending"),
        ("stoop", "bending"),
        ("squat", "crouching"),
        ("kneel", "crouching"),
        ("kneel2", "crouching"),
        ("sit", "crouching"),
        ("sit_floor", "crouching"),
        ("lie", "lying"),
    ],
)
@pytest.mark.parametrize("height", [1.55, 1.95])
def test_each_body_shape_is_the_posture_it_stands_for(shape, posture, height) -> None:
    standing = _one("stand", height)
    for fall_dir in np.linspace(-np.pi, np.pi, 7):
        J = _one(shape, height, fall_dir)
        got = classify(J, standing_hip_m=float(hips_z(standing)))
        assert got.posture == posture, (shape, fall_dir, got)
        assert J[:, 2].min() >= 0.02  # nothing sinks into the floor
        # every bone keeps its standing length
        for a, b in LIMBS:
            assert np.linalg.norm(J[a] - J[b]) == pytest.approx(
                np.linalg.norm(standing[a] - standing[b]), abs=1e-6
            )


def test_kneeling_has_a_knee_on_the_floor_and_sitting_on_the_floor_keeps_the_head_up() -> None:
    kneel = _one("kneel", 1.75)
    assert min(kneel[13, 2], kneel[14, 2]) < 0.08 < 0.4 < max(kneel[13, 2], kneel[14, 2])
    sit = _one("sit_floor", 1.75)
    assert hips_z(sit) < 0.2 and sit[0, 2] > 0.7


def test_a_fall_drops_the_hips_fast_and_a_get_up_is_slow() -> None:
    p, h = (5.0, 4.0), 0.0
    acts = (
        Act("walk", 0.0, 2.0, (3.0, 4.0), p, h),
        Act("fall", 2.0, 8.0, p, p, h, ease_s=0.7, fall_dir=1.0),
        Act("get_up", 8.0, 12.0, p, p, h, ease_s=3.0, fall_dir=1.0),
        Act("stand", 12.0, 14.0, p, p, h),
    )
    J, present = Actor(1.75, 1.8, 0.0, acts, (12.0, 8.0)).track(round(14 * FPS), FPS)
    assert present.all()
    z = hips_z(J)
    t = np.arange(z.size) / FPS
    assert z[t < 1.9].min() > 0.8 and z[(t > 3.0) & (t < 8.0)].max() < 0.4
    # down within a second, 0.2 s drops of the hips faster than 1.5 m/s
    k = round(0.2 * FPS)
    drop = (z[:-k] - z[k:]) / 0.2
    assert drop[(t[:-k] >= 2.0) & (t[:-k] < 3.0)].max() > 1.5
    assert drop.min() > -1.0  # rising takes seconds
    assert z[t >= 11.5].min() > 0.85
    for a, b in LIMBS:  # bones keep their lengths through the fall and the get-up
        d = np.linalg.norm(J[:, a] - J[:, b], axis=-1)
        assert np.ptp(d) < 1e-6
    assert np.nanmin(J[..., 2]) >= 0.02


@pytest.mark.slow
def test_postures_of_a_routine_scene_follow_the_script() -> None:
    bs = simulate_behaviour("routine", seed=4, difficulty="easy", duration_s=60.0)
    expect = {
        "kneel": "crouching",
        "kneel2": "crouching",
        "squat": "crouching",
        "sit": "crouching",
        "sit_floor": "crouching",
        "stoop": "bending",
    }
    tracker = PostureTracker(FPS)
    hits, seen = 0, 0
    for f, people in enumerate(truth_frames(bs.scene)):
        t = f / FPS
        postures = tracker.update(t, people)
        for n, actor in enumerate(bs.actors):
            act = next((a for a in actor.acts if a.t0 + a.ease_s + 0.5 <= t < a.t1), None)
            if act is not None and act.kind in expect and n + 1 in postures:
                seen += 1
                hits += postures[n + 1].posture == expect[act.kind]
    assert seen > 200 and hits >= 0.98 * seen
    assert not bs.falls
    assert not [e for e in truth_events(bs, scene_rules(bs)) if e.type == "person_down"]


@pytest.mark.slow
def test_true_person_down_follows_the_scripted_falls() -> None:
    found = {True: 0, False: 0}
    for seed in range(3):
        bs = simulate_behaviour("falls", seed=seed, difficulty="easy", duration_s=40.0)
        assert len(bs.falls) == 3 and sorted(f.worker for f in bs.falls) == [1, 2, 3]
        truth = truth_events(bs, scene_rules(bs))
        downs = [e for e in truth if e.type == "person_down"]
        for f in bs.falls:
            mine = [e for e in downs if e.person == f.worker]
            down = f.down_for(bs.duration_s)
            if down < 1.0:  # scrambled up at once: no alarm
                assert not mine, (seed, f, mine)
            elif down > bs.down_s + 0.5:  # raised down_s after the fall, about when it landed
                assert len(mine) == 1, (seed, f, mine)
                assert abs(mine[0].t - (f.t_floor + bs.down_s)) < 0.5
            else:  # the scene ends about down_s after the landing
                continue
            found[down >= 1.0] += 1
        assert len(downs) == sum(f.down_for(bs.duration_s) >= 1.0 for f in bs.falls)
    assert found[True] >= 4  # both kinds of fall were drawn
    assert found[False] >= 1


@pytest.mark.slow
def test_work_scene_truth_has_lone_workers_and_wrong_positions(work) -> None:
    bs, truth = work
    types = {e.type for e in truth}
    assert {"lone_worker", "lone_worker_end", "work_position"} <= types
    assert "person_down" not in types
    for e in truth:
        if e.type == "work_position":
            assert e.failed in ("position", "facing", "position,facing") and e.zone
    workers = {int(i): int(i) for i in bs.scene.ids}
    for t in ("lone_worker", "work_position"):
        m = evaluate_alarms(truth, truth, workers, t)
        assert m.precision == m.recall == 1.0 and m.matched == m.true > 0


@pytest.mark.slow
def test_alarm_matching_counts_misses_wrong_workers_and_late_alarms(work) -> None:
    bs, truth = work
    truth = [e for e in truth if e.type == "lone_worker"]
    assert len(truth) >= 3
    workers = {int(i): int(i) for i in bs.scene.ids}
    late = dataclasses.replace(truth[0], t=truth[0].t + 2.5)
    other = dataclasses.replace(truth[1], person=99)
    run = [late, other, *truth[2:]]
    m = evaluate_alarms(run, truth, workers, "lone_worker")
    assert (m.true, m.predicted, m.matched) == (len(truth), len(truth), len(truth) - 2)
    assert m.recall == m.precision == (len(truth) - 2) / len(truth)
    with pytest.raises(ValueError, match="alarm type"):
        evaluate_alarms(run, truth, workers, "lone_worker_end")


def test_bad_scene_requests_are_errors() -> None:
    with pytest.raises(ValueError, match="scene kind"):
        simulate_behaviour("party")
    with pytest.raises(ValueError, match="unknown act"):
        Actor(1.7, 1.8, 0.0, (Act("dance", 0.0, 1.0, (1.0, 1.0), (1.0, 1.0), 0.0),), (12.0, 8.0))
    with pytest.raises(ValueError, match="num_people"):
        simulate_behaviour("falls", num_people=0)


@pytest.mark.slow
def test_a_lying_body_is_reconstructed_tracked_and_raises_person_down() -> None:
    """The real 3D back end on a hard scene's detections: the fallen workers stay reconstructed
    and tracked while they lie (neither below the floor nor a ghost), their track's posture is
    lying, and the run raises person_down for each fall the truth does, in time."""
    bs = simulate_behaviour("falls", seed=1, difficulty="hard", duration_s=45.0)
    sc = bs.scene
    stage = Stage3D(sc.rig, dataclasses.replace(Config(), fps=sc.fps))
    preds = [stage.step(t, [d[n] for n in sc.rig.names]) for t, d in enumerate(sc.detections)]
    workers = track_workers(preds, sc)
    tracker, truth_tracker = PostureTracker(FPS), PostureTracker(FPS)
    truth = truth_frames(sc)
    lying = matched = lying_track = 0
    for t, p in enumerate(preds):
        true = truth_tracker.update(t / FPS, truth[t])
        got = tracker.update(t / FPS, p)
        idx = np.flatnonzero(sc.present[t])
        pairs = {int(sc.ids[idx[n]]): q for q, n in match_people(p.joints, sc.truth[t, idx])}
        for w, post in true.items():
            if post.posture != "lying":
                continue
            lying += 1
            if w in pairs:
                matched += 1
                pid = int(p.ids[pairs[w]])
                lying_track += workers.get(pid) == w and got[pid].posture == "lying"
    assert lying > 500
    assert matched >= 0.98 * lying and lying_track >= 0.95 * lying
    rules = scene_rules(bs)
    events, truth = monitor_events(bs, rules, preds), truth_events(bs, rules)
    falls = score_falls(bs, events, truth, workers)
    assert any(f.due for f in falls)
    for f in falls:
        if f.due:
            assert f.delay_s <= 2.0, f
        else:
            assert np.isnan(f.delay_s), f
    m = evaluate_alarms(events, truth, workers, "person_down")
    assert m.precision == m.recall == 1.0
