from __future__ import annotations

import numpy as np
import pytest

from stereopose.sim import Scene, evaluate, evaluate_tracking, match_people, truth_people3d
from stereopose.sim.metrics import detectable
from stereopose.types import People3D


def _truth(scene):
    return [truth_people3d(scene, t) for t in range(scene.num_frames)]


def _keep(p: People3D, mask: np.ndarray, joints: np.ndarray | None = None) -> People3D:
    return People3D(
        p.frame,
        p.joints[mask] if joints is None else joints,
        p.conf[mask],
        p.ids[mask],
        p.reprojection_px[mask],
        p.views[mask],
        p.detections[mask],
    )


def test_truth_people3d(mid_scene) -> None:
    p = truth_people3d(mid_scene, 10)
    n = int(mid_scene.present[10].sum())
    assert len(p) == n and p.detections.shape == (n, len(mid_scene.rig))
    assert np.all(p.detections == -1) and np.all(p.conf == 1)
    assert set(p.ids.tolist()) <= set(mid_scene.ids.tolist())


def test_ground_truth_scores_perfectly(mid_scene) -> None:
    m = evaluate(_truth(mid_scene), mid_scene)
    assert m.mpjpe_mm == 0.0 and m.pcp == 1.0 and m.pcp_seen == 1.0 and m.person_recall == 1.0
    assert m.false_people_per_frame == 0.0 and m.joint_coverage == 1.0
    assert m.frames == mid_scene.num_frames
    assert set(m.as_dict()) == {
        "mpjpe_mm",
        "pcp",
        "pcp_seen",
        "person_recall",
        "false_people_per_frame",
        "joint_coverage",
        "frames",
    }


def test_dropping_a_person_lowers_recall(mid_scene) -> None:
    preds = [_keep(p, p.ids != 1) for p in _truth(mid_scene)]
    counted = detectable(mid_scene)
    expected = 1.0 - counted[:, 0].sum() / counted.sum()
    m = evaluate(preds, mid_scene)
    assert m.person_recall == pytest.approx(expected)
    assert m.pcp == pytest.approx(expected)
    assert m.mpjpe_mm == 0.0 and m.false_people_per_frame == 0.0


def test_offsets_extra_people_and_missing_joints(mid_scene) -> None:
    truth = _truth(mid_scene)
    shifted = [
        _keep(p, np.ones(len(p), bool), p.joints + np.array([0.03, 0.04, 0.0])) for p in truth
    ]
    m = evaluate(shifted, mid_scene)
    assert m.mpjpe_mm == pytest.approx(50.0) and m.person_recall == 1.0
    far = np.full((1, 17, 3), 100.0)
    extra = [
        People3D(
            p.frame,
            np.concatenate([p.joints, far]),
            np.ones((len(p) + 1, 17)),
            np.arange(len(p) + 1),
            np.zeros((len(p) + 1, 17)),
            np.zeros((len(p) + 1, 17)),
            np.full((len(p) + 1, len(mid_scene.rig)), -1),
        )
        for p in truth
    ]
    assert evaluate(extra, mid_scene).false_people_per_frame == 1.0
    holed = []
    for p in truth:
        j = p.joints.copy()
        j[:, 9] = np.nan  # left wrist never reconstructed: the left forearm is wrong
        holed.append(_keep(p, np.ones(len(p), bool), j))
    m = evaluate(holed, mid_scene)
    assert m.joint_coverage == pytest.approx(16 / 17) and m.pcp == pytest.approx(0.9)
    assert m.mpjpe_mm == 0.0


def test_match_people() -> None:
    rng = np.random.default_rng(0)
    true = rng.uniform(0, 5, (4, 17, 3))
    perm = np.array([2, 0, 3, 1])
    pred = true[perm] + 0.01
    pred[1, :5] = np.nan
    pairs = match_people(pred, true)
    assert pairs == [(i, int(perm[i])) for i in range(4)]
    assert match_people(pred + 1.0, true) == []
    assert match_people(np.zeros((0, 17, 3)), true) == []
    assert match_people(pred[:2], true, max_dist_m=0.5) == [(0, 2), (1, 0)]


def test_tracking_metrics_of_the_truth_are_perfect(mid_scene: Scene) -> None:
    truth = [truth_people3d(mid_scene, t) for t in range(mid_scene.num_frames)]
    m = evaluate_tracking(truth, mid_scene)
    assert m.id_switches == 0 and m.fragmented == 0 and m.ghost_ids == 0
    assert m.ids == m.workers
    assert m.idf1 > 0.99 and m.mota > 0.99


def test_tracking_metrics_count_switches_and_ghosts(mid_scene: Scene) -> None:
    ok = detectable(mid_scene)
    w1, w2 = np.flatnonzero(ok[99] & ok[100])[:2]
    id1, id2 = mid_scene.ids[w1], mid_scene.ids[w2]
    preds = []
    for t in range(mid_scene.num_frames):
        p = truth_people3d(mid_scene, t)
        ids = p.ids.copy()
        if t >= 100:  # from frame 100 on, two workers exchange ids
            a, b = ids == id1, ids == id2
            ids[a], ids[b] = id2, id1
        joints, extra = p.joints, np.zeros(0, dtype=np.int64)
        if t == 50:  # a ghost somewhere nobody is
            joints = np.concatenate([joints, np.full((1, 17, 3), 50.0)])
            extra = np.array([99])
        preds.append(
            People3D(
                t,
                joints,
                np.ones(joints.shape[:2]),
                np.concatenate([ids, extra]),
                np.zeros(joints.shape[:2]),
                np.ones(joints.shape[:2], dtype=np.int64),
                np.full((len(joints), len(mid_scene.rig)), -1),
            )
        )
    m = evaluate_tracking(preds, mid_scene)
    assert m.id_switches == 2
    assert m.fragmented == 2 and m.ghost_ids == 1 and m.ids == m.workers + 1
    assert m.idf1 < 0.95
