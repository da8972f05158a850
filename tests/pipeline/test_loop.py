"""The frame loop: stages timed apart, progress, stop and Ctrl-C, and no growth with run length."""

from __future__ import annotations

import dataclasses
import io
import signal
import threading
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from stereopose.config import Config
from stereopose.geometry.camera import project
from stereopose.io.aggregates import RunningStats
from stereopose.io.summary import FILE_STAGES, RunSummary
from stereopose.pipeline.loop import FrameLoop, SourceStep
from stereopose.pipeline.outputs import Outputs, open_outputs
from stereopose.pipeline.step_rules import step_chain
from stereopose.sim import simulate
from stereopose.types import Event, People2D, People3D


class Steps:
    """`n` steps of the same two people seen by every camera of `rig`."""

    stages = FILE_STAGES
    live = False
    fps = 25.0

    def __init__(self, rig, n: int) -> None:
        self.rig, self.n = rig, n
        self.cameras = rig.names
        joints = np.array(
            [
                [[x + 0.1 * j, y, 1.0 + 0.05 * j] for j in range(17)]
                for x, y in ((5.0, 4.0), (7.0, 3.0))
            ]
        )
        self.people3d = People3D(
            0,
            joints,
            np.full((2, 17), 0.9),
            np.array([1, 2]),
            np.full((2, 17), 1.5),
            np.full((2, 17), 3),
            np.tile([0, 1], (len(rig), 1)).T,
        )
        self.people2d = {}
        for c in rig:
            uv = project(joints, c)
            kp = np.concatenate([uv + 0.7, np.full((2, 17, 1), 0.9)], axis=-1)
            self.people2d[c.name] = People2D(c.name, 0, kp)

    @property
    def total(self) -> int:
        return self.n

    def __iter__(self) -> Iterator[SourceStep]:
        for f in range(self.n):
            yield SourceStep(f, f / self.fps, self.people2d)

    def detect(self, step):
        raise TypeError

    def tracked(self, people) -> None:
        pass

    def finish(self, summary) -> None:
        pass


class SameStage:
    """A 3D stage that gives the same people every frame."""

    tracking = True

    def __init__(self, people: People3D) -> None:
        self.people = people
        self.loaded = 0

    def load(self) -> float:
        self.loaded += 1
        return 0.25

    def step(self, frame, people2d, t=None) -> People3D:
        return dataclasses.replace(self.people, frame=frame, t=t)

    def trajectories(self) -> list:
        return []

    def two_way(self, frames):
        return frames


class EveryHundred:
    """Fences raising one event every 100 frames."""

    def update(self, people: People3D) -> list[Event]:
        if people.frame % 100:
            return []
        return [
            Event(people.frame / 25, people.frame, 1, "z", "energized", "enter", people.frame / 25)
        ]


def footprint(obj, seen=None) -> int:
    """What an object holds, counted: container lengths and array sizes, through attributes,
    slots, mappings and sequences (files, threads and callables count nothing)."""
    seen = set() if seen is None else seen
    if id(obj) in seen or callable(obj) or isinstance(obj, (io.IOBase, threading.Thread)):
        return 0
    seen.add(id(obj))
    if isinstance(obj, np.ndarray):
        return obj.nbytes
    if isinstance(obj, (str, bytes, int, float, bool, type(None), Path)):
        return 1
    if isinstance(obj, dict):
        return len(obj) + sum(footprint(k, seen) + footprint(v, seen) for k, v in obj.items())
    if isinstance(obj, (list, tuple, set, frozenset)):
        return len(obj) + sum(footprint(v, seen) for v in obj)
    slots = [s for c in type(obj).__mro__ for s in getattr(c, "__slots__", ())]
    state = [getattr(obj, s) for s in slots if hasattr(obj, s)]
    state += list(getattr(obj, "__dict__", {}).values())
    return sum(footprint(v, seen) for v in state)


@pytest.fixture(scope="module")
def rig():
    return simulate(num_cameras=3, num_people=1, num_frames=1, seed=0).rig


def _loop(rig, tmp_path: Path, n: int, **kw):
    source = Steps(rig, n)
    stage = SameStage(source.people3d)
    summary = RunSummary(rig.names, FILE_STAGES, "robust", True)
    got: list = []
    outputs = Outputs(
        poses=tmp_path / "p.jsonl",
        events=tmp_path / "e.jsonl",
        events_db=tmp_path / "e.sqlite",
        trc_dir=tmp_path / "trc",
        csv=tmp_path / "j.csv",
        tracks=tmp_path / "tracks.json",
        summary=tmp_path / "summary.json",
    )
    from stereopose.fence import Site

    sinks = open_outputs(
        outputs,
        rig=rig,
        config=Config(),
        summary=summary,
        stage=stage,
        site=Site(()),
        on_events=got.extend,
    )
    return FrameLoop(source, stage, sinks, summary, rules=step_chain(EveryHundred()), **kw), got


def test_stages_are_timed_apart_and_progress_reported(rig, tmp_path: Path) -> None:
    calls = []
    loop, got = _loop(rig, tmp_path, 50, on_step=lambda *a: calls.append(a))
    s = loop.run()
    assert loop.stage.loaded == 1 and s.load_s_3d == 0.25  # loaded once, reported apart
    assert s.frames == 50 and [c[:2] for c in calls] == [(k, 50) for k in range(1, 51)]
    assert all(c[2] > 0 for c in calls)
    assert set(s.seconds) == {"read", "3d", "fences", "write"}
    assert all(v > 0 for v in s.seconds.values()) and s.wall_s >= sum(s.seconds.values())
    assert s.people_histogram == {2: 50} and len(got) == 1 and s.events == {"enter": 1}
    # the detections are 0.7 px off along x and y: 0.99 px, to the histogram's 0.025 px
    for cam in s.per_camera.values():
        assert cam.frames == 50 and cam.reprojection.median == pytest.approx(0.99, abs=0.03)


def test_stop_ends_the_run_after_the_current_frame(rig, tmp_path: Path) -> None:
    stop = threading.Event()
    loop, _ = _loop(rig, tmp_path, 50, stop=stop, on_step=lambda d, t, f: d == 3 and stop.set())
    s = loop.run()
    assert s.frames == 3 and s.interrupted
    assert len((tmp_path / "p.jsonl").read_text().splitlines()) == 3


def test_ctrl_c_stops_after_the_frame_and_twice_at_once(rig, tmp_path: Path) -> None:
    def interrupt(done, total, fps) -> None:
        if done in (4, 6):  # the second one, two frames later, stops at once
            signal.raise_signal(signal.SIGINT)

    before = signal.getsignal(signal.SIGINT)
    loop, _ = _loop(rig, tmp_path, 50, on_step=interrupt)
    loop.stop = threading.Event()
    s = loop.run()
    assert s.interrupted and s.frames == 4  # the first Ctrl-C: the frame finished, then stop
    assert signal.getsignal(signal.SIGINT) is before  # the handler given back
    assert len((tmp_path / "p.jsonl").read_text().splitlines()) == 4


@pytest.mark.slow
def test_state_does_not_grow_with_run_length(rig, tmp_path: Path) -> None:
    sizes = {}

    def measure(done, total, fps) -> None:
        if done in (1000, 10_000):
            sizes[done] = [footprint(loop.summary)] + [footprint(s) for s in loop.sinks]

    loop, _ = _loop(rig, tmp_path, 10_000, on_step=measure)
    loop.run()
    assert sizes[1000] == sizes[10_000]
    assert loop.summary.frames == 10_000 and sum(loop.summary.events.values()) == 100
    stats = loop.summary.per_camera["cam01"].reprojection
    assert stats.count == 10_000 * 34 and stats.nbytes == RunningStats().nbytes


# --- each step's time through the loop, and Ctrl-C while the source waits -------------------


class TimedSteps(Steps):
    """Steps at the given times (seconds), as a live source gives them: not frame / fps."""

    def __init__(self, rig, times: list[float]) -> None:
        super().__init__(rig, len(times))
        self.times = times

    def __iter__(self) -> Iterator[SourceStep]:
        for f, t in enumerate(self.times):
            yield SourceStep(f, t, self.people2d)


def test_each_steps_time_reaches_every_record(rig, tmp_path: Path) -> None:
    from stereopose.fence import FenceMonitor, Site, Zone
    from stereopose.io.results import read_poses
    from stereopose.io.sinks.events import read_events

    times = [0.0, 0.4, 0.45, 1.7, 2.0, 3.9, 4.0, 4.05]  # irregular, as frames arrive
    source = TimedSteps(rig, times)
    stage = SameStage(source.people3d)
    summary = RunSummary(rig.names, FILE_STAGES, "robust", True)
    zone = Zone(
        "z",
        "restricted",
        np.array([[4.0, 3.0], [6.0, 3.0], [6.0, 5.0], [4.0, 5.0]]),
        (0.0, 2.5),
        enter_s=0.3,
    )
    site = Site((zone,))
    outputs = Outputs(
        poses=tmp_path / "p.jsonl", events=tmp_path / "e.jsonl", csv=tmp_path / "j.csv"
    )
    sinks = open_outputs(outputs, rig=rig, config=Config(), summary=summary, stage=stage, site=site)
    FrameLoop(source, stage, sinks, summary, rules=step_chain(FenceMonitor(site, 25.0))).run()
    assert [t for _, t, _ in read_poses(tmp_path / "p.jsonl")] == times
    csv_times = {float(r.split(",")[1]) for r in (tmp_path / "j.csv").read_text().splitlines()[1:]}
    assert csv_times == set(times)
    (enter,) = read_events(tmp_path / "e.jsonl")
    # inside from t = 0 on, confirmed at the first step 0.3 s later: the step at t = 0.4
    assert (enter.type, enter.frame, enter.t, enter.onset_t) == ("enter", 1, 0.4, 0.0)


def test_the_tracker_follows_the_steps_time(scene) -> None:
    """The same frames, one 10 s gap in their times: tracks end (max_lost_s is 3 s of time,
    not 75 frames), and the people come back under new ids."""
    from stereopose.pipeline.stage3d import Stage3D

    def ids(times) -> list[set[int]]:
        stage = Stage3D(scene.rig, Config(fps=scene.fps))
        out = []
        for f, (t, d) in enumerate(zip(times, scene.detections, strict=True)):
            people = stage.step(f, d, t)
            assert people.t == t
            out.append(set(people.ids.tolist()))
        return out

    n = len(scene.detections)
    even = [f / scene.fps for f in range(n)]
    gap = [t + (10.0 if f >= n // 2 else 0.0) for f, t in enumerate(even)]
    steady, broken = ids(even), ids(gap)
    assert steady[n // 2 - 1] and steady[n // 2 - 1] <= steady[n // 2]  # they go on, same ids
    before, after = broken[n // 2 - 1], set().union(*broken[n // 2 :])
    assert before and after and not before & after


class Stalls(Steps):
    """`n` steps, then a wait for frames that never come (bounded, so a failing test ends)."""

    def __init__(self, rig, n: int) -> None:
        super().__init__(rig, n)
        self.waiting = threading.Event()

    @property
    def total(self) -> None:
        return None

    def __iter__(self) -> Iterator[SourceStep]:
        yield from super().__iter__()
        self.waiting.set()
        if threading.Event().wait(20):  # pragma: no cover - never set
            return
        raise AssertionError("Ctrl-C did not end the wait for the source")


def test_ctrl_c_while_the_source_waits_ends_the_run_at_once(rig, tmp_path: Path) -> None:
    source = Stalls(rig, 3)
    stage = SameStage(source.people3d)
    summary = RunSummary(rig.names, FILE_STAGES, "robust", True)
    outputs = Outputs(poses=tmp_path / "p.jsonl", summary=tmp_path / "summary.json")
    sinks = open_outputs(outputs, rig=rig, config=Config(), summary=summary, stage=stage, site=None)

    def interrupt() -> None:
        if source.waiting.wait(20):
            signal.pthread_kill(threading.main_thread().ident, signal.SIGINT)

    threading.Thread(target=interrupt, daemon=True).start()
    s = FrameLoop(source, stage, sinks, summary).run()  # the first Ctrl-C is enough
    assert s.interrupted and s.frames == 3 and s.error is None
    assert len((tmp_path / "p.jsonl").read_text().splitlines()) == 3
    assert '"interrupted": true' in (tmp_path / "summary.json").read_text()
