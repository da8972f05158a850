"""The service's steps around a stall, on a simulated scene through the real 3D stage, fences
and camera watch (on a clock the test steps): every camera late at once while their readers
deliver is one service_stalled, no camera_down, and the people keep their ids and their zones;
a real outage of every camera is still one camera_down each and ends the tracks."""

from __future__ import annotations

import numpy as np
import pytest

from stereopose.config import Config
from stereopose.fence import Site
from stereopose.pipeline.loop import SourceStep
from stereopose.pipeline.stage3d import Stage3D
from stereopose.site.health.watch import CameraWatch
from stereopose.site.site_switch import Outliving, site_rules
from stereopose.site.steps import HeldStage, ServeEvents, StepHooks
from stereopose.zones import Zone

TIMEOUT_S = 2.0
FLOOR = np.array([[-50.0, -50.0], [50.0, -50.0], [50.0, 50.0], [-50.0, 50.0]])


class Run:
    """The serve loop's order for each step: events.step, the 3D stage, the service's chain of
    step rules (site.site_switch.site_rules: the fences on the people's time, then the
    service's own events)."""

    def __init__(self, scene, fresh: bool | None) -> None:
        cfg = Config(fps=scene.fps)
        site = Site((Zone("floor", "work_area", FLOOR, (0.0, 2.5)),))
        watch = CameraWatch(scene.rig.names, TIMEOUT_S, start=0.0)
        self.now = 0.0
        hooks = StepHooks(
            fresh=None if fresh is None else (lambda name: fresh), clock=lambda: self.now
        )
        self.events = ServeEvents(watch, None, hooks)
        self.rules = site_rules(site, self.events, cfg, Outliving())
        self.stage = HeldStage(Stage3D(scene.rig, cfg), self.events.time)
        self.scene, self.frame = scene, 0
        self.ids: list[set[int]] = []
        self.log: list = []

    def step(self, t: float, f: int | None) -> None:
        """A step at t with the scene's frame f (None: a heartbeat, no camera delivered)."""
        self.now = max(self.now, t)
        people2d = {} if f is None else dict(self.scene.detections[f])
        images = None if f is None else {n: np.zeros((2, 2, 3), np.uint8) for n in people2d}
        step = SourceStep(self.frame, t, people2d, images)
        self.frame += 1
        self.events.step(step)
        people = self.stage.step(step.frame, people2d, t)
        assert people.t == pytest.approx(t)
        self.log += self.rules.chain.step(t, step.frame, people)[0]
        if f is not None:
            self.ids.append(set(people.ids.tolist()))

    def types(self) -> list[str]:
        return [e.type for e in self.log]


def _run(scene, fresh: bool | None, stall_s: float, heartbeats: bool, stale: bool = False) -> Run:
    """The scene's first half, a stall of stall_s, its second half. stale: the first step
    after a pause holds frames read just before it."""
    run, dt = Run(scene, fresh), 1.0 / scene.fps
    n = len(scene.detections)
    for f in range(n // 2 - int(stale)):
        run.step(f * dt, f)
    t = (n // 2 - 1) * dt
    if heartbeats:  # the loop beats every 0.5 s while no step with frames comes
        for k in range(1, int(stall_s / 0.5) + 1):
            run.step(t + 0.5 * k, None)
    else:  # the loop itself did not run (the process stopped): the clock went on
        run.now = t + stall_s
        if stale:
            run.step(t, n // 2 - 1)
    for f in range(n // 2, n):
        run.step(f * dt + stall_s, f)
    return run


@pytest.mark.parametrize(
    ("heartbeats", "stale"),
    [(True, False), (False, False), (False, True)],
    ids=["cameras-late", "loop-paused", "loop-paused-stale-step"],
)
def test_a_stall_is_one_service_event_and_the_people_keep_their_ids(scene, heartbeats, stale):
    run = _run(scene, fresh=True, stall_s=8.0, heartbeats=heartbeats, stale=stale)
    n = len(scene.detections)
    assert run.types().count("service_stalled") == 1
    assert run.types().count("service_resumed") == 1
    assert "camera_down" not in run.types() and "camera_up" not in run.types()
    before, after = run.ids[n // 2 - 1], run.ids[n // 2]
    assert before and after == before  # the same ids across the stall
    assert not [e for e in run.log if e.type == "exit"]  # nobody left the floor, nobody lost
    stalled = next(e for e in run.log if e.type == "service_stalled")
    resumed = next(e for e in run.log if e.type == "service_resumed")
    assert (stalled.kind, stalled.zone, stalled.person) == ("service", "", -1)
    assert resumed.duration_s == pytest.approx(8.0 + 1 / scene.fps, abs=0.6)
    # the people's stages leave the stall out, their events stay on the service's clock
    assert run.events.held_s > 6.0
    last = run.log[-1] if run.log else None
    assert last is None or last.t <= (n - 1) / scene.fps + 8.0 + 1e-6


def test_every_camera_really_silent_is_one_camera_down_each_and_ends_the_tracks(scene):
    run = _run(scene, fresh=False, stall_s=8.0, heartbeats=True)
    n = len(scene.detections)
    types = run.types()
    assert "service_stalled" not in types
    assert sorted(e.camera for e in run.log if e.type == "camera_down") == sorted(scene.rig.names)
    lost = [e for e in run.log if e.type == "exit" and e.lost]
    assert lost  # their tracks ended while the cameras were blind
    assert not run.ids[n // 2 - 1] & run.ids[-1]


def test_without_reader_news_two_cameras_late_at_once_is_a_stall(scene) -> None:
    run = _run(scene, fresh=None, stall_s=3.0, heartbeats=True)
    assert run.types().count("service_stalled") == 1 and "camera_down" not in run.types()


def test_heartbeats_while_the_readers_deliver_are_no_observation(scene) -> None:
    """A slow step (under the timeout): the heartbeats in between do not drop anybody, and
    the people's time is not held."""
    run = _run(scene, fresh=True, stall_s=1.5, heartbeats=True)
    n = len(scene.detections)
    assert run.types() == [e.type for e in run.log if e.type in ("enter",)]
    assert run.events.held_s == 0.0
    assert run.ids[n // 2] == run.ids[n // 2 - 1]
