"""Per-frame reconstruction on simulated scenes: exactness, robustness, bad input."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from stereopose.config import (
    MODES,
    Config,
    ReconstructionConfig,
    TrackingConfig,
    TriangulationConfig,
)
from stereopose.pipeline.stage3d import Stage3D
from stereopose.reconstruction import Reconstructor
from stereopose.sim import DetectorNoise, evaluate, simulate
from stereopose.skeleton import NUM_JOINTS, SWAP
from stereopose.types import People2D

CLEAN = DetectorNoise.exact()


def config(mode: str = "robust", **kw) -> ReconstructionConfig:
    return ReconstructionConfig(triangulation=TriangulationConfig(mode=mode, **kw))


def run(scene, cfg=None):
    rec = Reconstructor(scene.rig, cfg or config())
    return [rec(t, dets) for t, dets in enumerate(scene.detections)]


@pytest.fixture(scope="module")
def clean_scene():
    return simulate(num_cameras=5, num_people=3, num_frames=20, seed=4, noise=CLEAN)


@pytest.mark.parametrize("mode", MODES)
def test_noise_free_detections_give_the_truth(clean_scene, mode):
    m = evaluate(run(clean_scene, config(mode)), clean_scene)
    assert m.person_recall == 1.0
    assert m.false_people_per_frame == 0.0
    assert m.mpjpe_mm < 1.0  # occluded joints carry detector error even here
    assert m.pcp > 0.99


def test_output_contract(clean_scene):
    rec = Reconstructor(clean_scene.rig, config())
    out = rec(3, clean_scene.detections[3])
    P, C = len(out), len(clean_scene.rig)
    assert out.frame == 3
    assert out.joints.shape == (P, NUM_JOINTS, 3)
    assert out.conf.shape == out.reprojection_px.shape == out.views.shape == (P, NUM_JOINTS)
    assert out.detections.shape == (P, C)
    # every reconstructed joint rests on a view (one: placed from one view, see below); each
    # detection used at most once
    ok = np.isfinite(out.joints).all(-1)
    assert (out.views[ok] >= 1).all()
    assert (out.views[~ok] == 0).all()
    for c in range(C):
        used = out.detections[:, c][out.detections[:, c] >= 0]
        assert len(used) == len(set(used.tolist()))


@pytest.mark.parametrize("difficulty", ["mid", "hard"])
def test_robust_beats_the_reference_pair_mode(difficulty):
    scene = simulate(num_frames=60, seed=11, difficulty=difficulty)
    pair = evaluate(run(scene, config("pair")), scene)
    robust = evaluate(run(scene, config("robust")), scene)
    assert robust.mpjpe_mm < 0.7 * pair.mpjpe_mm
    assert robust.pcp > pair.pcp
    assert robust.person_recall >= 0.97
    assert robust.false_people_per_frame <= 0.1


def _swap_cameras(scene, t, names):
    dets = dict(scene.detections[t])
    for n in names:
        dets[n] = People2D(n, t, dets[n].keypoints[:, SWAP])
    return dets


@pytest.mark.parametrize("swapped", [1, 2])
def test_left_right_swaps_are_corrected(clean_scene, swapped):
    rec = Reconstructor(clean_scene.rig, config())
    names = clean_scene.rig.names[:swapped]
    errors = []
    for t in range(0, 20, 4):
        out = rec(t, _swap_cameras(clean_scene, t, names))
        truth = clean_scene.truth[t, clean_scene.present[t]]
        for p in range(len(out)):
            d = np.linalg.norm(out.joints[p][None] - truth, axis=-1)
            errors.append(np.nanmean(d, axis=1).min())
    assert len(errors) > 0
    assert np.max(errors) < 0.02  # metres: labels restored, not mirrored


def test_permutation_invariance(clean_scene):
    """Reordering cameras or the people within a camera changes nothing but the order."""
    rng = np.random.default_rng(0)
    t = 7
    rec = Reconstructor(clean_scene.rig, config())
    ref = rec(t, clean_scene.detections[t])
    perm_rig = clean_scene.rig.subset(list(rng.permutation(clean_scene.rig.names)))
    shuffled = {
        n: People2D(n, t, p.keypoints[rng.permutation(len(p))])
        for n, p in clean_scene.detections[t].items()
    }
    out = Reconstructor(perm_rig, config())(t, shuffled)
    assert len(out) == len(ref)
    key = lambda J: tuple(np.round(np.nanmean(J, axis=0), 6))  # noqa: E731
    a = sorted(key(J) for J in ref.joints)
    b = sorted(key(J) for J in out.joints)
    np.testing.assert_allclose(np.array(a), np.array(b), atol=1e-6)


def test_ghosts_are_not_people():
    noise = dataclasses.replace(CLEAN, ghosts=1.0)
    scene = simulate(num_cameras=6, num_people=2, num_frames=30, seed=2, noise=noise)
    m = evaluate(run(scene), scene)
    assert m.false_people_per_frame < 0.05
    assert m.person_recall > 0.98


@pytest.mark.parametrize(("cameras", "people"), [(2, 1), (3, 0), (8, 6), (10, 10)])
def test_any_number_of_cameras_and_people(cameras, people):
    scene = simulate(
        num_cameras=cameras, num_people=people, num_frames=8, seed=5, difficulty="easy"
    )
    preds = run(scene)
    assert len(preds) == 8
    if people == 0:
        assert all(len(p) == 0 for p in preds)
    else:
        m = evaluate(preds, scene)
        assert m.person_recall > 0.9
        assert m.false_people_per_frame < 0.2


def test_empty_and_degenerate_frames(clean_scene):
    rec = Reconstructor(clean_scene.rig, config())
    names = clean_scene.rig.names
    assert len(rec(0, {})) == 0
    assert len(rec(0, {n: People2D.empty(n, 0) for n in names})) == 0
    one_camera = {names[0]: clean_scene.detections[0][names[0]]}
    assert len(rec(0, one_camera)) == 0
    nan_people = {n: People2D(n, 0, np.full((2, NUM_JOINTS, 3), np.nan)) for n in names}
    assert len(rec(0, nan_people)) == 0
    with pytest.raises(ValueError, match="expected people for 5 cameras, got 2"):
        rec(0, [None, None])


def test_people_below_the_floor_or_too_tall_are_dropped(clean_scene):
    """The same detections seen through a rig shifted 2 m up put everyone below the floor."""
    t = 5
    shifted = clean_scene.rig.subset(clean_scene.rig.names)
    cams = []
    for c in shifted:
        # world moved 2 m down relative to the camera: t' = t + R (0, 0, 2)
        cams.append(dataclasses.replace(c, translation=c.translation + c.R @ np.array([0, 0, 2.5])))
    from stereopose.types import Rig

    low = Reconstructor(Rig(tuple(cams)), config())(t, clean_scene.detections[t])
    assert len(low) == 0
    ok = Reconstructor(clean_scene.rig, config())(t, clean_scene.detections[t])
    assert len(ok) > 0


def _keep_one_view(scene, t, worker, joint):
    """Frame t's detections with `joint` of `worker` left in one camera only (the first that
    reports it); returns them and that camera's name."""
    dets, kept = dict(scene.detections[t]), None
    for name in scene.rig.names:
        owners = scene.detection_truth[t][name]
        rows = np.flatnonzero(owners == worker)
        if rows.size == 0 or dets[name].keypoints[rows[0], joint, 2] <= 0:
            continue
        if kept is None:
            kept = name
            continue
        kp = dets[name].keypoints.copy()
        kp[rows[0], joint] = (np.nan, np.nan, 0.0)
        dets[name] = People2D(name, t, kp)
    return dets, kept


@pytest.mark.parametrize("joint", [9, 15, 0])  # left wrist, left ankle, nose
def test_a_joint_seen_in_one_view_is_placed_within_a_bone_length(clean_scene, joint):
    t = 5
    worker = int(np.flatnonzero(clean_scene.present[t])[0])
    dets, kept = _keep_one_view(clean_scene, t, worker, joint)
    assert kept is not None
    truth = clean_scene.truth[t, worker]
    on = Reconstructor(clean_scene.rig, config())(t, dets)
    off = Reconstructor(clean_scene.rig, config(single_view=False))(t, dets)
    p = int(np.argmin(np.nanmean(np.linalg.norm(on.joints - truth, axis=-1), axis=1)))
    q = int(np.argmin(np.nanmean(np.linalg.norm(off.joints - truth, axis=-1), axis=1)))
    assert np.isnan(off.joints[q, joint]).all()
    assert on.views[p, joint] == 1
    # on the kept view's ray, and no farther from the truth than the bone to its anchor
    anchor = {9: 7, 15: 13, 0: 1}[joint]
    bone = np.linalg.norm(truth[joint] - truth[anchor])
    assert np.linalg.norm(on.joints[p, joint] - truth[joint]) <= bone + 0.01
    assert on.reprojection_px[p, joint] < 1.0
    # its confidence says it has no depth of its own; the other joints are untouched
    assert on.conf[p, joint] < 0.6 * off.conf[q].max()
    others = np.arange(NUM_JOINTS) != joint
    np.testing.assert_allclose(on.joints[p, others], off.joints[q, others], atol=1e-9)


def test_a_joint_seen_in_one_view_does_not_make_a_person(clean_scene):
    """Placing single-view joints adds no people: the plausibility test counts only joints
    that rest on two views or more."""
    for t in (0, 7, 14):
        on = Reconstructor(clean_scene.rig, config())(t, clean_scene.detections[t])
        off = Reconstructor(clean_scene.rig, config(single_view=False))(
            t, clean_scene.detections[t]
        )
        assert len(on) == len(off)


def _mirrored_faceless(scene, t):
    """Frame t's detections with left and right exchanged in every camera and the face
    (nose, eyes, ears) unseen: a mirror no single frame can tell from the truth."""
    dets = {}
    for name, p in scene.detections[t].items():
        kp = p.keypoints[:, SWAP].copy()
        kp[:, :5] = (np.nan, np.nan, 0.0)
        dets[name] = People2D(name, t, kp)
    return dets


def _mirror_error(out, scene, t):
    """Per person of out, metres from the nearest true worker, and from that worker mirrored."""
    truth = scene.truth[t, scene.present[t]]
    d = np.nanmean(np.linalg.norm(out.joints[:, None] - truth[None], axis=-1), axis=-1)
    dm = np.nanmean(np.linalg.norm(out.joints[:, None] - truth[None][:, :, SWAP], axis=-1), -1)
    return d.min(1), dm.min(1)


def _per_frame(rig, cfg: ReconstructionConfig):
    """Frame-by-frame 3D people with the memory of the per-frame mode (recent people)."""
    return Stage3D(rig, Config(reconstruction=cfg, tracking=TrackingConfig(memory="recent"))).step


def _continuity(frames: int, mode: str = "robust") -> ReconstructionConfig:
    cfg = config(mode)
    return dataclasses.replace(
        cfg, association=dataclasses.replace(cfg.association, continuity_frames=frames)
    )


def test_consecutive_frames_carry_labels_over(clean_scene):
    t = 6
    alone = Reconstructor(clean_scene.rig, config())(t, _mirrored_faceless(clean_scene, t))
    right, mirrored = _mirror_error(alone, clean_scene, t)
    assert len(alone) == clean_scene.present[t].sum()
    assert (mirrored < 0.01).all() and (right > 0.05).all()  # on its own: the mirror
    rec = _per_frame(clean_scene.rig, config())
    for s in range(t):
        rec(s, clean_scene.detections[s])
    out = rec(t, _mirrored_faceless(clean_scene, t))
    # the reconstruction itself holds nothing between frames: the same call, the same people
    again = Reconstructor(clean_scene.rig, config())
    for s in range(t):
        again(s, clean_scene.detections[s])
    np.testing.assert_array_equal(again(t, _mirrored_faceless(clean_scene, t)).joints, alone.joints)
    right, mirrored = _mirror_error(out, clean_scene, t)
    assert len(out) == len(alone)
    assert (right < 0.01).all() and (mirrored > 0.05).all()  # labels from the frames before


def test_people_missed_for_a_frame_still_carry_over(clean_scene):
    t, names = 6, clean_scene.rig.names
    results = {}
    for frames in (1, 3):
        rec = _per_frame(clean_scene.rig, _continuity(frames))
        for s in range(t - 1):
            rec(s, clean_scene.detections[s])
        assert len(rec(t - 1, {n: People2D.empty(n, t - 1) for n in names})) == 0
        results[frames] = _mirror_error(rec(t, _mirrored_faceless(clean_scene, t)), clean_scene, t)
    assert (results[1][1] < 0.01).all()  # remembered one frame: the mirror
    assert (results[3][0] < 0.01).all()  # remembered three: the truth


@pytest.mark.parametrize(
    ("frames", "mode", "t"), [(0, "robust", 6), (3, "pair", 6), (3, "robust", 2)]
)
def test_frames_out_of_order_or_without_continuity_stand_alone(clean_scene, frames, mode, t):
    """Without continuity (or in pair mode) every frame stands alone; with it, a frame that
    does not follow the last one (t = 2 after frame 5) starts afresh."""
    cfg = _continuity(frames, mode)
    rec = _per_frame(clean_scene.rig, cfg)
    for s in range(6):
        rec(s, clean_scene.detections[s])
    dets = _mirrored_faceless(clean_scene, t)
    out = rec(t, dets)
    ref = Reconstructor(clean_scene.rig, cfg)(t, dets)
    np.testing.assert_array_equal(out.joints, ref.joints)
