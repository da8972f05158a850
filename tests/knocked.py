"""A yard camera knocked out of place mid-run, and the calibration keeper run over its steps
(the keeper's and its API's tests)."""

from __future__ import annotations

import numpy as np

from stereopose.calibration.formats import save_calibration
from stereopose.config import Config
from stereopose.io.sinks.base import FrameResult
from stereopose.pipeline.stage3d import Stage3D
from stereopose.sim.yard import bump, yard_scene
from stereopose.site.health.calib_health import CalibrationHealth
from stereopose.site.health.calib_keeper import CalibrationKeeper, KeeperSettings
from stereopose.types import Rig

KNOCKED_AT = 600  # frame (step 300)


def knocked_yard(steps_to: int = 1500):
    """(the rig as calibrated, the camera as it is after the knock, the steps' people2d)."""
    before = yard_scene(seed=3, walkers=2, duration_s=60.0)
    rig = before.rig
    moved = bump(rig["cam02"], np.random.default_rng(4), 1.5, 0.3)
    after = yard_scene(
        seed=3,
        walkers=2,
        duration_s=60.0,
        rig=Rig(tuple(moved if c.name == "cam02" else c for c in rig)),
    )
    steps = [
        before.detections[t] if t < KNOCKED_AT else after.detections[t]
        for t in range(0, steps_to, 2)
    ]
    return rig, moved, steps


def run_keeper(rig, steps, tmp_path, auto: bool):
    """The 3D stage, the calibration health and a keeper (calib.toml in tmp_path) over the
    steps: (the keeper, every calibration event, the rigs it applied)."""
    save_calibration(tmp_path / "calib.toml", rig)
    stage = Stage3D(rig, Config())
    health = CalibrationHealth(rig, 2.0, baseline_samples=60, window=30)
    applied = []
    keeper = CalibrationKeeper(
        rig,
        tmp_path / "calib.toml",
        health,
        apply=[stage.set_rig, applied.append],
        settings=KeeperSettings(auto, 60),
    )
    events = []
    for k, people2d in enumerate(steps):
        t = k * 0.08
        p3 = stage.step(k, people2d, t)
        drift = health.update(FrameResult(k, t, people2d, p3, []))
        events += drift
        events += keeper.update(k, t, people2d, drift)
        case = keeper.cases.get("cam02")
        if case is not None and case.job is not None:
            case.job.result(timeout=60)  # the worker's attempt, judged at the next step
    keeper.close()
    return keeper, events, applied


def proposed_keeper(folder):
    """A keeper (calibration_auto = false) with a pose proposed for the knocked cam02, not yet
    accepted: (the keeper, the rigs it applied, the steps)."""
    rig, _, steps = knocked_yard(steps_to=1040)
    keeper, _, applied = run_keeper(rig, steps, folder, auto=False)
    assert "cam02" in keeper.proposals()
    return keeper, applied, steps


def surveyed_yard(folder, bumped_deg: float = 2.0):
    """A simulated yard with its surveyed points, its running rig cam02 bumped `bumped_deg`
    (0: none), and a keeper over the running rig (calibration_auto = false; its files in
    `folder`): (the true rig, the points file's JSON, the true clicks, the keeper, the rigs it
    applied)."""
    from stereopose.sim.yard import survey, yard_rig

    rng = np.random.default_rng(5)
    truth = yard_rig(rng)
    world, clicks = survey(truth, rng)
    moved = bump(truth["cam02"], np.random.default_rng(6), bumped_deg, 0.0)
    running = Rig(tuple(moved if c.name == "cam02" else c for c in truth))
    save_calibration(folder / "calib.toml", running)
    applied: list[Rig] = []
    keeper = CalibrationKeeper(
        running,
        folder / "calib.toml",
        CalibrationHealth(running, 2.0),
        apply=[applied.append],
        settings=KeeperSettings(auto=False),
        out_dir=folder / "out",
    )
    doc = {
        "points": {k: v.tolist() for k, v in world.items()},
        "cameras": {c: {k: v.tolist() for k, v in t.items()} for c, t in clicks.items()},
    }
    return truth, doc, clicks, keeper, applied
