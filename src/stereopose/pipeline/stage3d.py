"""The 3D stage of the frame loop: prior -> reconstruct -> update, one frame at a time.

The reconstruction of a frame is stateless (given the prior); the memory of past frames (the
Kalman tracker, or the lighter "recent people" of the per-frame mode) gives the prior and turns
the frame's reconstructed people into the output people.

Each domain compiles its loops with numba, cached beside its module: the first process on a
machine compiles them (`make install` does, with load_compiled), later ones load them from the
cache. Either costs time once per process, which a run spends before its first frame
(Stage3D.load) and reports apart from the stage's frames/s.
"""

from __future__ import annotations

import dataclasses
import functools
import time
from collections.abc import Mapping, Sequence

from stereopose.config import Config, ReconstructionConfig, TrackingConfig
from stereopose.errors import CalibrationError
from stereopose.reconstruction import Reconstructor
from stereopose.tracking import Trajectory
from stereopose.tracking.ids import IdSource
from stereopose.tracking.memory import make_memory
from stereopose.types import People2D, People3D, Rig


class Stage3D:
    """Association, triangulation and the memory of past frames, for one rig.

    record: keep every track's measurements, for `two_way` (the tracker's memory only).
    first_id: the tracker's first person id (a restarted service continues above its log's).
    """

    def __init__(
        self,
        rig: Rig,
        config: Config | None = None,
        *,
        record: bool = False,
        calib_path: str = "",
        first_id: int | IdSource = 1,
    ) -> None:
        config = config or Config()
        try:
            self.reconstructor = Reconstructor(rig, config.reconstruction)
        except CalibrationError as e:
            raise CalibrationError(f"{calib_path}: {e}" if calib_path else str(e)) from None
        self.memory = make_memory(rig, config, record=record, first_id=first_id)
        self.tracking = self.memory.tracking
        self.fps = float(config.fps)
        self._warm = (config.reconstruction, config.tracking, record)
        self.load_s: float | None = None  # time the compiled loops took to load, once

    def set_rig(self, rig: Rig) -> None:
        """The rig from the next frame on (a camera placed again); the tracks go on."""
        self.reconstructor = Reconstructor(rig, self._warm[0])

    def load(self) -> float:
        """Load (or compile) the compiled loops once, before the first frame; returns the
        seconds it took, which the stage's frames/s leave out."""
        if self.load_s is None:
            t0 = time.perf_counter()
            _load(*self._warm)  # the loops this stage's configuration runs
            self.load_s = time.perf_counter() - t0
        return self.load_s

    def step(
        self,
        frame: int,
        people2d: Mapping[str, People2D] | Sequence[People2D | None],
        t: float | None = None,
    ) -> People3D:
        """One frame's output people: ids, joints (smoothed when tracking), positions, stamped
        with the frame's time t in seconds (None: frame / fps; live cameras give their frames'
        arrival time, which the tracker predicts to)."""
        t = frame / self.fps if t is None else float(t)
        prior = self.memory.prior(frame, t)
        rec = self.reconstructor.reconstruct(frame, people2d, prior)
        return self.memory.update(frame, rec).at(t)

    def trajectories(self) -> list[Trajectory]:
        """Every tracked person's trajectory so far, by id (none without tracking)."""
        return self.memory.finish()

    def two_way(self, frames: Sequence[People3D]) -> list[People3D]:
        """The online output `frames` smoothed both ways over each track (needs record)."""
        return self.memory.two_way(frames)


def load_compiled() -> None:
    """Load (compiling the ones not cached yet) every compiled loop of the 3D stage, with the
    argument types a run uses: the tracker with two-way smoothing, and the per-frame robust
    mode. `make install` runs it once, so later processes find them all in the cache."""
    tracking = TrackingConfig()
    _load(ReconstructionConfig(), tracking, True)
    _load(ReconstructionConfig(), dataclasses.replace(tracking, enabled=False), False)


@functools.cache
def _load(reconstruction: ReconstructionConfig, tracking: TrackingConfig, record: bool) -> None:
    """Run a small simulated scene through a 3D stage of this configuration (and its two-way
    smoothing with record), which loads the compiled loops it calls. Once per process and
    configuration."""
    from stereopose.sim import simulate

    scene = simulate(num_cameras=3, num_people=2, num_frames=6, seed=1, difficulty="hard")
    config = Config(fps=scene.fps, reconstruction=reconstruction, tracking=tracking)
    stage = Stage3D(scene.rig, config, record=record)
    people = [
        stage.step(t, [d[n] for n in scene.rig.names]) for t, d in enumerate(scene.detections)
    ]
    if record:
        stage.two_way(people)
