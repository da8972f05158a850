"""Identities over time on simulated scenes and on the shared real detections."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from stereopose.config import Config, with_overrides
from stereopose.pipeline.stage3d import Stage3D
from stereopose.sim import evaluate, evaluate_tracking, simulate
from stereopose.sim.scene import Scene, ghost_frame
from stereopose.types import People2D


def frames_of(scene: Scene) -> list[list[People2D | None]]:
    return [[d[name] for name in scene.rig.names] for d in scene.detections]


def track(scene: Scene, frames=None, **tracking):
    cfg = with_overrides(dataclasses.replace(Config(), fps=scene.fps), tracking=tracking)
    tracker = Stage3D(scene.rig, cfg)
    frames = frames_of(scene) if frames is None else frames
    return [tracker.step(t, f) for t, f in enumerate(frames)], tracker


@pytest.mark.slow
@pytest.mark.parametrize(
    ("difficulty", "seed"), [("easy", 1), ("mid", 2), ("hard", 3), ("hard", 4)]
)
def test_ids_persist_through_entries_exits_and_crowds(difficulty: str, seed: int) -> None:
    scene = simulate(difficulty=difficulty, num_frames=200, seed=seed, p_enter=0.5, p_leave=0.5)
    preds, tracker = track(scene)
    m = evaluate_tracking(preds, scene)
    assert m.id_switches <= 1
    assert m.ids <= m.workers + 1 and m.ghost_ids == 0
    assert m.idf1 > 0.95
    # every worker who entered or left did so under one id
    assert m.fragmented <= 1
    assert [t.id for t in tracker.trajectories()] == sorted({int(i) for p in preds for i in p.ids})


@pytest.mark.parametrize(("length", "gets_id"), [(1, False), (2, False), (6, True)])
def test_a_ghost_gets_an_id_only_once_confirmed(length: int, gets_id: bool) -> None:
    scene = simulate(difficulty="easy", num_frames=40, seed=11, p_enter=0.0, p_leave=0.0)
    frames = frames_of(scene)
    for t in range(20, 20 + length):
        frames[t] = ghost_frame(scene, t, (1.0, 1.0))
    preds, _ = track(scene, frames)
    ids = {int(i) for p in preds for i in p.ids}
    workers = len(np.flatnonzero(scene.present.any(0)))
    assert len(ids) == workers + gets_id


@pytest.mark.slow
def test_ids_survive_cameras_dropping_out() -> None:
    """Two of six cameras deliver nothing for a second; then every camera stalls for 0.4 s."""
    scene = simulate(difficulty="mid", num_frames=150, seed=5, p_enter=0.0, p_leave=0.0)
    frames = frames_of(scene)
    for t in range(30, 55):
        frames[t][1] = frames[t][4] = None
    stall = range(90, 100)
    for t in stall:
        frames[t] = [None] * len(scene.rig)
    preds, _ = track(scene, frames)
    m = evaluate_tracking(preds, scene)
    assert m.id_switches == 0 and m.ids == m.workers
    # the stall: bridged by prediction for bridge_s, then nobody until the cameras return
    assert all(p.predicted.all() for p in preds[90:95])
    assert all(len(p) == 0 for p in preds[96:100])
    assert len(preds[100]) == m.workers and not preds[100].predicted.any()


@pytest.mark.slow
def test_online_smoothing_lowers_the_joint_error() -> None:
    scene = simulate(difficulty="mid", num_frames=200, seed=6)
    raw = evaluate(track(scene, smoothing=False)[0], scene).mpjpe_mm
    smooth = evaluate(track(scene)[0], scene).mpjpe_mm
    assert smooth < 0.9 * raw


def test_nobody_seen_then_tracks_end_after_max_lost() -> None:
    scene = simulate(difficulty="easy", num_frames=10, seed=2, p_enter=0.0, p_leave=0.0)
    cfg = dataclasses.replace(Config(), fps=25.0)
    tracker = Stage3D(scene.rig, cfg)
    for t, f in enumerate(frames_of(scene)):
        tracker.step(t, f)
    assert len(tracker.memory) == 2
    empty = [None] * len(scene.rig)
    out = tracker.step(10, empty)
    assert out.predicted.all() and len(out) == 2
    out = tracker.step(20, empty)
    assert len(out) == 0 and len(tracker.memory) == 2  # lost, not ended
    tracker.step(10 + int(25 * cfg.tracking.max_lost_s) + 1, empty)
    assert len(tracker.memory) == 0
    assert [t.frames_seen for t in tracker.trajectories()] == [10, 10]


def run_with_zone(scene: Scene, frame_numbers: list[int]):
    """Tracked people and zone events of scene's frames numbered `frame_numbers`, with one
    work area around the whole scene."""
    from stereopose.fence import FenceMonitor, Site, Zone

    cfg = dataclasses.replace(Config(), fps=scene.fps)
    stage = Stage3D(scene.rig, cfg)
    zone = Zone("hall", "work_area", np.array([[-50, -50], [50, -50], [50, 50], [-50, 50]]), (0, 3))
    fences = FenceMonitor(Site((zone,)), cfg.fps, cfg.tracking.max_lost_s)
    out, events = [], []
    for n, people2d in zip(frame_numbers, frames_of(scene), strict=False):
        people = stage.step(n, people2d)
        out.append(people)
        events += fences.update(people)
    return out, events, stage


@pytest.mark.parametrize("jump", [10**3, 10**6, 2**53 - 100])
def test_a_jump_in_frame_numbers_ends_the_tracks_lost_too_long(jump: int) -> None:
    """Frames 0-18, then frame numbers far ahead: the people there are new tracks, and the
    people inside the zone before the jump exit it (lost) at the first frame after it."""
    scene = simulate(difficulty="easy", num_frames=30, seed=11, p_enter=0.0, p_leave=0.0)
    numbers = list(range(19)) + list(range(jump, jump + 11))
    out, events, stage = run_with_zone(scene, numbers)
    before = {int(i) for p in out[:19] for i in p.ids}
    after = {int(i) for p in out[19:] for i in p.ids}
    assert len(before) == 2 and len(after) == 2 and not before & after
    assert not any(p.predicted.any() for p in out[19:])
    exits = [e for e in events if e.type == "exit"]
    assert sorted(e.person for e in exits) == sorted(before)
    assert all(e.lost and e.frame == jump for e in exits)
    enters = sorted(e.person for e in events if e.type == "enter")
    assert enters == sorted(before | after)
    ended = {t.id: t for t in stage.trajectories()}
    assert all(ended[i].last_frame == 18 for i in before)


def test_a_frame_that_does_not_come_later_is_skipped(caplog) -> None:
    """A repeated or earlier frame number gives nobody, with a warning, and leaves the tracks
    exactly as they were: the frames after it come out as if it had not been there."""
    scene = simulate(difficulty="easy", num_frames=12, seed=2, p_enter=0.0, p_leave=0.0)
    frames = frames_of(scene)
    clean, _ = track(scene, frames)
    cfg = dataclasses.replace(Config(), fps=scene.fps)
    stage = Stage3D(scene.rig, cfg)
    got = []
    with caplog.at_level("WARNING"):
        for t, f in enumerate(frames):
            got.append(stage.step(t, f))
            if t == 6:
                assert len(stage.step(6, frames[6])) == 0  # repeated
                assert len(stage.step(2, frames[2])) == 0  # back in time
    assert "frame 6 does not come after frame 6" in caplog.text
    assert "frame 2 does not come after frame 6" in caplog.text
    for a, b in zip(clean, got, strict=True):
        assert a.ids.tolist() == b.ids.tolist()
        np.testing.assert_array_equal(a.joints, b.joints)


@pytest.mark.realdata
def test_real_people_keep_one_id_each(shared_data_dir) -> None:
    from stereopose.calibration.formats import load_calibration
    from stereopose.detection.openpose import read_pose_dir

    rig = load_calibration(shared_data_dir / "calib.toml")
    seq = read_pose_dir(shared_data_dir / "pose", rig.names)
    tracker = Stage3D(rig, dataclasses.replace(Config(), fps=60.0))
    frames = {}
    for frame, people in seq:
        out = tracker.step(frame, people)
        frames[frame] = {int(i): out.joints[k] for k, i in enumerate(out.ids)}
    trajectories = tracker.trajectories()
    # the two main people are the ones seen longest; each is one id from start to end
    main = sorted(trajectories, key=lambda t: -t.frames_seen)[:2]
    assert all(t.first_frame == 0 and t.last_frame == 99 for t in main)
    for t in main:
        seen = [f for f in frames if t.id in frames[f]]
        assert seen == list(range(seq.frames[0] + 2, 100))  # all frames once confirmed
    # the ids stay on the same bodies: no jump of the hips between frames
    for t in main:
        hips = np.array([frames[f][t.id][11:13].mean(0) for f in range(2, 100)])
        assert np.nanmax(np.linalg.norm(np.diff(hips, axis=0), axis=-1)) < 0.1


def test_a_joint_one_camera_sees_is_bridged_by_its_track() -> None:
    """A joint tracked from two views that one camera alone then sees is predicted (its depth
    from one view leans on a neighbour); a joint never measured takes the one-view placement."""
    scene = simulate(num_cameras=4, num_people=1, num_frames=12, seed=3, difficulty="easy")
    frames = frames_of(scene)
    joint, first = 9, 8  # left wrist: from frame 8 on, only the first camera reporting it keeps it
    for t in range(first, len(frames)):
        kept = False
        for c, people in enumerate(frames[t]):
            if people is None or len(people) == 0:
                continue
            kp = people.keypoints.copy()
            if kp[0, joint, 2] > 0 and not kept:
                kept = True
                continue
            kp[:, joint] = (np.nan, np.nan, 0.0)
            frames[t][c] = People2D(people.camera, t, kp, people.boxes, people.scores)
    out, _ = track(scene, frames)
    later = [p for p in out if p.frame >= first and len(p)]
    assert later
    for p in later[:3]:  # within bridge_s of its last two-view measurement
        assert p.views[0, joint] == 0
        assert np.isfinite(p.joints[0, joint]).all()
        truth = scene.truth[p.frame, 0, joint]
        assert np.linalg.norm(p.joints[0, joint] - truth) < 0.1


def test_ended_trajectories_are_bounded(monkeypatch) -> None:
    """A service runs for weeks: of the ended tracks, only the latest trajectories are kept."""
    from stereopose.tracking import tracker as tracker_module

    monkeypatch.setattr(tracker_module, "MAX_ENDED_TRAJECTORIES", 1)
    scene = simulate(difficulty="easy", num_frames=10, seed=2, p_enter=0.0, p_leave=0.0)
    cfg = dataclasses.replace(Config(), fps=25.0)
    tracker = Stage3D(scene.rig, cfg)
    for t, f in enumerate(frames_of(scene)):
        tracker.step(t, f)
    tracker.step(10 + int(25 * cfg.tracking.max_lost_s) + 1, [None] * len(scene.rig))
    kept = tracker.trajectories()
    assert len(kept) == 1 and tracker.memory.trajectories_dropped == 1
    assert kept[0].id == 2 and kept[0].frames_seen == 10  # the later of the two ended
