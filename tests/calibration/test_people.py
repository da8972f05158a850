"""The rig from people on a simulated yard (40 x 25 m, 6 pole cameras, a detector with misses,
swaps and ghosts): one walker, several, scale from a distance or a height, and the errors
of a recording the method cannot use."""

from __future__ import annotations

import numpy as np
import pytest

from stereopose.calibration.people import calibrate_people
from stereopose.errors import CalibrationError
from stereopose.sim.yard import rig_errors, yard_scene
from stereopose.types import Camera, Rig

pytestmark = pytest.mark.slow


def _bare(rig: Rig) -> Rig:
    return Rig(
        tuple(Camera(c.name, c.size, c.matrix, c.distortions, [0, 0, 0], [0, 0, 1]) for c in rig)
    )


def _frames(yard, stride: int) -> list:
    return [(t, yard.detections[t]) for t in range(0, len(yard.detections), stride)]


def _check(result, truth: Rig, rot_deg: float, pos_m: float, scale: float) -> dict:
    e = rig_errors(result.rig, truth)
    assert np.median(list(e["rotation_deg"].values())) < rot_deg, e
    assert max(e["position_m"].values()) < pos_m, e
    assert abs(e["scale"] - 1) < scale, e
    assert abs(e["floor_m"]) < 0.05 and e["tilt_deg"] < 0.3, e
    return e


def test_one_walker_gives_the_rig_with_the_scale_of_one_distance() -> None:
    yard = yard_scene(seed=1, walkers=1, duration_s=60.0)
    truth = yard.rig
    d = float(np.linalg.norm(truth[0].center - truth[3].center))
    r = calibrate_people(_frames(yard, 4), _bare(truth), distance=("cam01", "cam04", d))
    _check(r, truth, rot_deg=0.1, pos_m=0.15, scale=0.01)
    assert "cam01-cam04" in r.scale_from
    assert all(e < 3.0 for e in r.camera_rms_px.values())
    assert all(n > 500 for n in r.joints_used.values())


def test_three_walkers_and_their_height_for_the_scale() -> None:
    yard = yard_scene(seed=2, walkers=3, duration_s=30.0)
    height = float(np.mean(yard.heights))  # as a crew's mean height would be given
    r = calibrate_people(_frames(yard, 5), _bare(yard.rig), height_m=height)
    e = rig_errors(r.rig, yard.rig)
    assert np.median(list(e["rotation_deg"].values())) < 0.1, e
    assert abs(e["scale"] - 1) < 0.04, e  # the eyes at 0.936 of the height, give or take
    # (the cameras' heights, 6-9 m, carry the scale's error)
    assert abs(e["floor_m"]) < 0.05 + 9 * abs(e["scale"] - 1) and e["tilt_deg"] < 0.3, e
    assert "height" in r.scale_from


def test_a_camera_no_walker_reaches_is_named() -> None:
    yard = yard_scene(seed=1, walkers=1, duration_s=20.0)
    frames = [
        (n, {k: v for k, v in people.items() if k != "cam05"}) for n, people in _frames(yard, 4)
    ]
    d = float(np.linalg.norm(yard.rig[0].center - yard.rig[3].center))
    with pytest.raises(CalibrationError, match="cam05 share no walker"):
        calibrate_people(frames, _bare(yard.rig), distance=("cam01", "cam04", d))


def test_nobody_seen_is_an_error() -> None:
    yard = yard_scene(seed=1, walkers=1, duration_s=2.0)
    empty = [
        (n, {k: type(v)(k, n, np.zeros((0, 17, 3))) for k, v in p.items()})
        for n, p in _frames(yard, 1)
    ]
    with pytest.raises(CalibrationError, match="no person"):
        calibrate_people(empty, _bare(yard.rig), height_m=1.75)


def test_exactly_one_scale() -> None:
    yard = yard_scene(seed=1, walkers=1, duration_s=2.0)
    with pytest.raises(CalibrationError, match="exactly one scale"):
        calibrate_people(
            _frames(yard, 1), _bare(yard.rig), height_m=1.7, distance=("cam01", "cam02", 3.0)
        )


def test_surveyed_points_give_the_scale_and_the_site_frame() -> None:
    from pathlib import Path

    from stereopose.calibration.surveyed import Survey
    from stereopose.sim.yard import survey

    yard = yard_scene(seed=1, walkers=1, duration_s=60.0)
    world, clicks = survey(yard.rig, np.random.default_rng(2))
    r = calibrate_people(
        _frames(yard, 4), _bare(yard.rig), survey=Survey(Path("points.toml"), world, clicks)
    )
    assert r.scale_from == "surveyed points (12)"
    for cam in yard.rig:  # the points' own frame: no alignment
        new = r.rig[cam.name]
        turn = np.degrees(np.arccos(np.clip((np.trace(new.R.T @ cam.R) - 1) / 2, -1, 1)))
        assert turn < 0.1, (cam.name, turn)
        assert np.linalg.norm(new.center - cam.center) < 0.1, cam.name
