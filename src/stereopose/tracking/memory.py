"""The memory of past frames behind one small interface, chosen by name in the configuration.

A memory gives the prior of a frame (the poses expected in it, which seed its reconstruction)
and turns that frame's reconstructed people into the output people:

    prior = memory.prior(frame, t)
    people = memory.update(frame, reconstructor.reconstruct(frame, people2d, prior))

- ``tracker``: the Kalman tracker (persistent ids, online smoothing, trajectories);
- ``recent``: the people of the last ``continuity_frames`` frames seed the next one, so a
  person keeps their grouping and left/right labels from frame to frame; ids 0..P-1 per frame;
- ``none``: every frame on its own.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Protocol

import numpy as np

from stereopose.config import Config
from stereopose.reconstruction import Reconstruction
from stereopose.skeleton import NUM_JOINTS
from stereopose.tracking.ids import IdSource
from stereopose.tracking.positioning import Trajectory
from stereopose.types import People3D, Rig

MEMORIES = ("tracker", "recent", "none")


class Memory(Protocol):
    """What the 3D stage keeps between frames; frames come in increasing order."""

    tracking: bool  # the output ids persist over time

    def prior(self, frame: int, t: float | None = None) -> np.ndarray | None:
        """(T, 17, 3) poses expected at `frame`, at time t seconds (None: frame / fps), NaN
        where unknown, or None."""
        ...

    def update(self, frame: int, rec: Reconstruction) -> People3D:
        """The output people of `frame` from its reconstruction (seeded by `prior`)."""
        ...

    def finish(self) -> list[Trajectory]:
        """Every person's trajectory, by id (empty without tracking)."""
        ...

    def two_way(self, frames: Sequence[People3D]) -> list[People3D]:
        """The online output smoothed both ways over each track (tracker with record only)."""
        ...


class NoMemory:
    """Every frame on its own: no prior; the reconstructed people as they are."""

    tracking = False

    def prior(self, frame: int, t: float | None = None) -> np.ndarray | None:
        return None

    def update(self, frame: int, rec: Reconstruction) -> People3D:
        return rec.people

    def finish(self) -> list[Trajectory]:
        return []

    def two_way(self, frames: Sequence[People3D]) -> list[People3D]:
        raise ValueError("two-way smoothing needs tracking (person ids)")


class RecentPeople(NoMemory):
    """The people seen in the last `frames` frames seed the next frame.

    A person seen now replaces the recent person that seeded them; a recent person no one
    continues stays until `frames` frames have passed. A frame that does not come after the
    last one starts afresh. Holds at most the people of `frames` frames.
    """

    def __init__(self, frames: int) -> None:
        self.frames = int(frames)
        self._joints = np.zeros((0, NUM_JOINTS, 3))
        self._seen = np.zeros(0, dtype=np.int64)  # frame each was last seen
        self._last: int | None = None

    def prior(self, frame: int, t: float | None = None) -> np.ndarray | None:
        if self._last is None or frame <= self._last:
            self._joints, self._seen = self._joints[:0], self._seen[:0]
        recent = frame - self._seen <= self.frames
        self._joints, self._seen = self._joints[recent], self._seen[recent]
        self._last = frame
        return self._joints if len(self._joints) else None

    def update(self, frame: int, rec: Reconstruction) -> People3D:
        missed = np.ones(len(self._joints), dtype=bool)
        missed[rec.seeds[rec.seeds >= 0]] = False
        self._joints = np.concatenate([rec.people.joints, self._joints[missed]])
        self._seen = np.concatenate(
            [np.full(len(rec.people), frame, dtype=np.int64), self._seen[missed]]
        )
        return rec.people


def make_memory(
    rig: Rig, config: Config, record: bool = False, first_id: int | IdSource = 1
) -> Memory:
    """The memory named by config.tracking.memory (`tracking.enabled = false` asks for
    `recent`, as before). record: the tracker keeps every measurement for two_way. first_id:
    the tracker's first id, or the IdSource it takes its ids from (tracking.ids); the other
    memories number each frame's people from 0."""
    name = config.tracking.memory if config.tracking.enabled else "recent"
    if record and not config.tracking.ids:
        raise ValueError("two-way smoothing needs tracking (person ids)")
    if config.tracking.ids:
        from stereopose.tracking.tracker import Tracker

        return Tracker(rig, config, record=record, first_id=first_id)
    rc = config.reconstruction
    frames = rc.association.continuity_frames
    if name == "recent" and rc.triangulation.mode == "robust" and frames > 0:
        return RecentPeople(frames)
    return NoMemory()
