"""The calibration's health: on the real detections, one camera turned by a few degrees (its
detections moved as the image of a rotated camera) raises calibration_drift for it alone, and
calibration_recovered once it is back; the rule itself on generated sequences."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from stereopose.calibration.formats import load_calibration
from stereopose.detection.openpose import read_pose_dir
from stereopose.io.records import event_from_record, event_record
from stereopose.io.sinks.base import FrameResult
from stereopose.reconstruction import Reconstructor
from stereopose.site.health.calib_health import CalibrationHealth
from stereopose.types import Camera, People2D


def turned(p2: People2D, cam: Camera, degrees: float) -> People2D:
    """The detections as a camera turned by `degrees` about its vertical axis would see them
    (pixels through the lens model: undistorted, rotated as rays, distorted again)."""
    kp = np.array(p2.keypoints, dtype=float)
    xy = kp[..., :2].reshape(-1, 2)
    ok = np.isfinite(xy).all(-1)
    rays = cv2.undistortPoints(xy[ok].reshape(-1, 1, 2), cam.matrix, cam.distortions)
    rays = np.c_[rays.reshape(-1, 2), np.ones(ok.sum())]
    R = cv2.Rodrigues(np.array([0.0, np.radians(degrees), 0.0]))[0]
    moved, _ = cv2.projectPoints(rays @ R.T, np.zeros(3), np.zeros(3), cam.matrix, cam.distortions)
    xy[ok] = moved.reshape(-1, 2)
    kp[..., :2] = xy.reshape((*kp.shape[:-1], 2))
    return dataclasses.replace(p2, keypoints=kp)


@pytest.mark.realdata
def test_a_camera_knocked_out_of_place_raises_a_drift_for_it_alone(shared_data_dir: Path) -> None:
    rig = load_calibration(shared_data_dir / "calib.toml")
    frames = list(read_pose_dir(shared_data_dir / "pose", rig.names))
    rec = Reconstructor(rig)
    # baseline and window span the whole clip, so that its harder moments (a person hidden from
    # one camera near its end) are part of every camera's normal figure, as a long run's are
    health = CalibrationHealth(rig, warn_factor=2.0, baseline_samples=100, window=100)
    events, n = [], 0
    for degrees in (0.0, 3.0, 0.0):  # in place, knocked by 3 degrees, put back
        for f, people2d in frames:
            if degrees:
                people2d = {**people2d, "cam02": turned(people2d["cam02"], rig["cam02"], degrees)}
            n += 1
            events += health.update(FrameResult(n, n / 60, people2d, rec(f, people2d)))
    assert [(e.type, e.camera) for e in events] == [
        ("calibration_drift", "cam02"),
        ("calibration_recovered", "cam02"),
    ]
    drift, back = events
    assert 100 < drift.frame <= 200  # within the window after the knock
    assert drift.reprojection_px > 2.0 * drift.baseline_px
    assert back.frame > 200 and back.reprojection_px < 2.0 * back.baseline_px
    assert (drift.kind, drift.zone, drift.person) == ("camera", "", -1)
    assert event_from_record(event_record(drift)).baseline_px == pytest.approx(
        drift.baseline_px, abs=1e-3
    )
    figures = health.figures()
    assert not any(f["drifting"] for f in figures.values())
    assert all(f["baseline_px"] is not None for f in figures.values())


class _OneCamera:
    names = ("c",)

    def __iter__(self):
        return iter(())

    def __len__(self) -> int:
        return 1


@settings(max_examples=200, deadline=None)
@given(st.lists(st.floats(0.0, 50.0), min_size=1, max_size=300), st.floats(1.2, 4.0))
def test_drift_and_recovery_alternate_and_follow_the_threshold(values, factor) -> None:
    health = CalibrationHealth(_OneCamera(), warn_factor=factor, baseline_samples=10, window=5)
    kinds = []
    for i, v in enumerate(values):
        for e in health.add("c", v, float(i), i):
            kinds.append(e.type)
            base = max(e.baseline_px, 1.0)
            if e.type == "calibration_drift":
                assert e.reprojection_px > factor * base
            else:
                assert e.reprojection_px < factor * base
    assert kinds == ["calibration_drift", "calibration_recovered"] * (len(kinds) // 2) + (
        ["calibration_drift"] if len(kinds) % 2 else []
    )
    cam = health.cameras["c"]
    assert len(cam.recent) <= 5 and len(cam.first) <= 10  # bounded however long it runs


def test_settings_out_of_range_are_refused() -> None:
    with pytest.raises(ValueError, match="warn_factor"):
        CalibrationHealth(_OneCamera(), warn_factor=1.0)
    with pytest.raises(ValueError, match="window"):
        CalibrationHealth(_OneCamera(), window=0)
