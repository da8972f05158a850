"""What the frame-loop tests share: a simulated scene as a source, a polling helper."""

from __future__ import annotations

from collections.abc import Iterator

from stereopose.io.summary import FILE_STAGES, RunSummary
from stereopose.pipeline.loop import SourceStep
from stereopose.sim import Scene


class SceneSource:
    """A simulated scene's detections, frame by frame, as keypoint files would give them;
    `fail_at`: raise `error` instead of giving that frame."""

    stages = FILE_STAGES
    live = False

    def __init__(self, scene: Scene, fail_at: int | None = None, error=RuntimeError) -> None:
        self.scene, self.fail_at, self.error = scene, fail_at, error
        self.cameras = scene.rig.names
        self.fps = scene.fps
        self.finished = False

    @property
    def total(self) -> int:
        return len(self.scene.detections)

    def __iter__(self) -> Iterator[SourceStep]:
        for f, people2d in enumerate(self.scene.detections):
            if f == self.fail_at:
                raise self.error(f"source failed at frame {f}")
            yield SourceStep(f, f / self.fps, people2d)

    def detect(self, step):
        raise TypeError

    def tracked(self, people) -> None:
        pass

    def finish(self, summary: RunSummary) -> None:
        self.finished = True
