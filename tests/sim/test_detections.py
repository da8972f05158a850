from __future__ import annotations

import numpy as np
import pytest

from stereopose.sim.detections import DetectorNoise, project_visible
from stereopose.skeleton import SWAP

UPPER = np.arange(1, 13)


def _pairs(scene):
    """(detected (17, 3), true pixels (17, 2), in-image (17,), back to camera) per detection."""
    out = []
    for c, cam in enumerate(scene.rig):
        uv, ok = project_visible(scene.truth, cam)
        lr = scene.truth[:, :, 5] - scene.truth[:, :, 6]
        facing = np.stack([lr[..., 1], -lr[..., 0]], axis=-1)
        to_cam = cam.center[:2] - 0.5 * (scene.truth[:, :, 5, :2] + scene.truth[:, :, 6, :2])
        back = np.sum(facing * to_cam, axis=-1) < 0
        for t in range(scene.num_frames):
            people = scene.detections[t][cam.name]
            for kp, n in zip(people.keypoints, scene.detection_truth[t][cam.name], strict=True):
                if n >= 0:
                    out.append((kp, uv[t, n], ok[t, n], back[t, n], c))
    return out


def _box_height(uv: np.ndarray, ok: np.ndarray) -> float:
    return float(np.ptp(uv[ok, 1]))


def test_presets() -> None:
    easy, mid, hard = (DetectorNoise.preset(d) for d in ("easy", "mid", "hard"))
    assert (easy.sigma_frac, mid.sigma_frac, hard.sigma_frac) == (0.006, 0.01, 0.015)
    assert (easy.swap, mid.swap, hard.swap) == (0.0, 0.05, 0.15)
    assert (easy.ghosts, mid.ghosts, hard.ghosts) == (0.0, 0.05, 0.15)
    with pytest.raises(ValueError, match="unknown difficulty"):
        DetectorNoise.preset("medium")


def test_detections_are_well_formed(mid_scene) -> None:
    for t, frame in enumerate(mid_scene.detections):
        assert set(frame) == set(mid_scene.rig.names)
        for name, people in frame.items():
            who = mid_scene.detection_truth[t][name]
            assert who.shape == (len(people),) and people.frame == t
            kp = people.keypoints
            valid = kp[..., 2] > 0
            assert np.all(valid.sum(1) >= 5)
            assert np.isnan(kp[~valid][:, :2]).all()
            box = people.boxes
            assert np.all(kp[..., 0][valid] >= np.repeat(box[:, 0], 17)[valid.ravel()] - 1e-9)
            assert np.all(kp[..., 1][valid] <= np.repeat(box[:, 3], 17)[valid.ravel()] + 1e-9)
            if len(people):
                mean_conf = np.nanmean(np.where(valid, kp[..., 2], np.nan), axis=1)
                assert np.allclose(people.scores, mean_conf)
            ids = who[who >= 0]
            assert len(set(ids.tolist())) == len(ids)  # one detection per worker per camera
            assert np.all(mid_scene.present[t, ids])


def _noise_ratio(scene) -> float:
    """Median pixel error / box height of confident joints, forgiving left/right swaps."""
    ratios = []
    for kp, uv, ok, _, _ in _pairs(scene):
        good = (kp[:, 2] >= 0.6) & ok & ok[SWAP]
        err = np.minimum(
            np.linalg.norm(kp[:, :2] - uv, axis=-1), np.linalg.norm(kp[:, :2] - uv[SWAP], axis=-1)
        )
        ratios.append(err[good] / max(_box_height(uv, ok), 10.0))
    return float(np.median(np.concatenate(ratios)))


def test_noise_scales_with_difficulty(easy_scene, mid_scene, hard_scene) -> None:
    # median of a 2D Gaussian radius is 1.1774 sigma
    for scene, sigma in ((easy_scene, 0.006), (mid_scene, 0.01), (hard_scene, 0.015)):
        assert _noise_ratio(scene) == pytest.approx(1.1774 * sigma, rel=0.15), scene.difficulty


def test_swap_rate_matches_preset(hard_scene, easy_scene) -> None:
    def rates(scene):
        counts = {False: [0, 0], True: [0, 0]}
        for kp, uv, ok, back, _ in _pairs(scene):
            use = UPPER[(kp[UPPER, 2] >= 0.6) & ok[UPPER]]
            # only views that show the shoulders well apart tell left from right
            if len(use) < 6 or np.linalg.norm(uv[5] - uv[6]) < 0.12 * _box_height(uv, ok):
                continue
            straight = np.linalg.norm(kp[use, :2] - uv[use], axis=-1).sum()
            swapped = np.linalg.norm(kp[use, :2] - uv[SWAP[use]], axis=-1).sum()
            counts[bool(back)][0] += swapped < straight
            counts[bool(back)][1] += 1
        return {k: v[0] / v[1] for k, v in counts.items()}, min(v[1] for v in counts.values())

    hard, n = rates(hard_scene)
    assert n > 1000
    assert hard[False] == pytest.approx(0.15, abs=0.04)
    assert hard[True] == pytest.approx(0.30, abs=0.05)
    easy, _ = rates(easy_scene)
    assert easy[False] < 0.01 and easy[True] < 0.01


def test_ghosts(hard_scene, easy_scene) -> None:
    ghosts = [
        people.keypoints[who < 0]
        for frame, labels in zip(hard_scene.detections, hard_scene.detection_truth, strict=True)
        for people, who in ((frame[k], labels[k]) for k in hard_scene.rig.names)
    ]
    per_view = np.array([len(g) for g in ghosts])
    assert per_view.mean() == pytest.approx(0.15, abs=0.03)  # preset: 0.15 per camera, frame
    conf = np.concatenate(ghosts)[..., 2]
    conf = conf[conf > 0]
    assert conf.min() >= 0.3 and conf.max() <= 0.8
    for labels in easy_scene.detection_truth:
        assert all(np.all(who >= 0) for who in labels.values())


def test_missed_people_and_shuffled_order(hard_scene) -> None:
    in_view = sum(
        len(labels[k]) - int(np.sum(labels[k] < 0))
        for labels in hard_scene.detection_truth
        for k in hard_scene.rig.names
    )
    assert in_view > 0
    orders = [
        labels[k][labels[k] >= 0]
        for labels in hard_scene.detection_truth
        for k in hard_scene.rig.names
    ]
    assert any(np.any(np.diff(o) < 0) for o in orders)
