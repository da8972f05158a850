"""Statistics sinks: per-camera reprojection figures and the summary."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from stereopose.geometry.camera import project, project_to_rig
from stereopose.io.sinks import CameraStatsSink, FrameResult, SummarySink
from stereopose.io.sinks.stats import reprojection_errors
from stereopose.io.summary import FILE_STAGES, RunSummary
from stereopose.sim import simulate
from stereopose.skeleton import SWAP
from stereopose.types import Event, People2D, People3D


def per_person(camera, joints, conf, detection) -> np.ndarray:
    """The reprojection errors of one person, one order at a time (the reference form)."""
    px = project(joints, camera)
    best = None
    for order in (slice(None), SWAP):
        kp = detection[order]
        ok = (kp[:, 2] > 0.5) & (conf > 0.5) & np.isfinite(px[:, 0])
        d = np.linalg.norm(px[ok] - kp[ok, :2], axis=1)
        if len(d) and (best is None or np.median(d) < np.median(best)):
            best = d
    return best if best is not None else np.zeros(0)


@pytest.mark.parametrize("seed", range(4))
def test_reprojection_errors_match_the_per_person_form(seed: int) -> None:
    rng = np.random.default_rng(seed)
    cam = simulate(num_cameras=2, num_people=1, num_frames=1, seed=seed).rig[0]
    S = 6
    joints = rng.uniform([3, 2, 0], [9, 6, 1.9], (S, 17, 3))
    joints[rng.random((S, 17)) < 0.1] = np.nan
    conf = rng.uniform(0, 1, (S, 17))
    uv = project(joints, cam) + rng.normal(0, 3, (S, 17, 2))
    det = np.concatenate([uv, rng.uniform(0, 1, (S, 17, 1))], axis=-1)
    det[~np.isfinite(uv).all(-1)] = (np.nan, np.nan, 0.0)  # as People2D keeps a missing joint
    det[1] = det[1][SWAP]  # a detection with its left and right exchanged
    det[2, :, 2] = 0.0  # one with no confident joint
    d, ok = reprojection_errors(project(joints, cam), conf, det)
    got = d[ok]
    want = np.concatenate([per_person(cam, joints[p], conf[p], det[p]) for p in range(S)])
    np.testing.assert_allclose(np.sort(got), np.sort(want))


def test_projection_into_the_rig_is_each_cameras_projection() -> None:
    rig = simulate(num_cameras=4, num_people=1, num_frames=1, seed=3).rig
    X = np.random.default_rng(0).uniform([-2, -2, -0.5], [10, 8, 2.5], (5, 17, 3))
    X[0, :4] = np.nan
    got = project_to_rig(X, rig)
    assert got.shape == (5, 17, 4, 2)
    for c, cam in enumerate(rig):
        np.testing.assert_allclose(got[..., c, :], project(X, cam), rtol=1e-12, atol=1e-9)
    assert np.isnan(got[0, :4]).all() and np.isfinite(got).sum() > 200


def test_camera_and_summary_sinks(tmp_path: Path) -> None:
    scene = simulate(num_cameras=3, num_people=1, num_frames=1, seed=1)
    rig = scene.rig
    J = scene.truth[0, :1]
    people = People3D(
        7,
        J,
        np.full((1, 17), 0.9),
        np.array([3]),
        np.full((1, 17), 1.0),
        np.full((1, 17), 3),
        np.zeros((1, 3), int),
    )
    p2 = {}
    for c in rig.cameras[:2]:  # the third camera has no frame here
        kp = np.concatenate([project(J, c) + np.array([3.0, 4.0]), np.full((1, 17, 1), 0.9)], -1)
        p2[c.name] = People2D(c.name, 7, kp)
    summary = RunSummary(rig.names, FILE_STAGES)
    sinks = [CameraStatsSink(rig, summary.per_camera), SummarySink(summary, tmp_path / "s.json")]
    ev = Event(0.28, 7, 3, "z", "energized", "enter", 0.2)
    for sink in sinks:
        sink.write(FrameResult(7, 0.28, p2, people, [ev]))
    assert sinks[1].close() == [tmp_path / "s.json"] and sinks[1].close() == []
    s = json.loads((tmp_path / "s.json").read_text())
    for name in rig.names[:2]:
        c = s["per_camera"][name]
        assert c["frames"] == 1 and c["detections_per_frame"] == 1.0
        assert c["reprojection_median_px"] == pytest.approx(5.0, abs=0.0251)  # (3, 4) px off
    assert s["per_camera"][rig.names[2]]["frames"] == 0
    assert s["frames"] == 1 and s["events"] == {"enter": 1} and s["people_histogram"] == {"1": 1}
    assert s["reprojection_median_px"] == pytest.approx(5.0, abs=0.0251)
    assert s["reprojection_mean_px"] == 1.0 and s["joints_reconstructed"] == 17
