"""Loading the compiled loops of the 3D stage once, before the first frame.

Each domain compiles its loops with numba, cached beside its module: the first process on a
machine compiles them (`make install` does), later ones load them from the cache. Either costs
time once per process, which a run does before its first frame and reports apart from the
stage's frames/s.
"""

from __future__ import annotations

import dataclasses
import functools

from stereopose.config import Config


@functools.cache
def load_compiled() -> None:
    """Run a small simulated scene through the 3D stage (tracker, per-frame robust mode and
    two-way smoothing), which loads every compiled loop with the argument types a run uses,
    compiling the ones not cached yet. Once per process."""
    from stereopose.pipeline.stage3d import Stage3D
    from stereopose.sim import simulate

    scene = simulate(num_cameras=3, num_people=2, num_frames=6, seed=1, difficulty="hard")
    config = dataclasses.replace(Config(), fps=scene.fps)
    per_frame = dataclasses.replace(
        config, tracking=dataclasses.replace(config.tracking, enabled=False)
    )
    for cfg, record in ((config, True), (per_frame, False)):
        stage = Stage3D(scene.rig, cfg, record=record)
        people = [
            stage.step(t, [d[n] for n in scene.rig.names]) for t, d in enumerate(scene.detections)
        ]
        if record:
            stage.two_way(people)
