"""What the frame-loop tests share: a simulated scene as a source, a polling helper."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from stereopose.io.summary import FILE_STAGES, RunSummary
from stereopose.pipeline.loop import SourceStep
from stereopose.sim import Scene


def wait_until(condition: Callable[[], bool], what: str, timeout_s: float = 20.0) -> None:
    """Poll ``condition()`` until it is true; fail if ``timeout_s`` passes first."""
    deadline = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() > deadline:
            pytest.fail(f"still waiting for {what} after {timeout_s} s")
        time.sleep(0.01)


def listening(port: int) -> bool:
    """Whether a socket listens on TCP ``port``, seen without connecting: ffmpeg ``-listen 1``
    takes the first client that connects as its only one, so a probe would use it up."""
    tables = [Path("/proc/net/tcp"), Path("/proc/net/tcp6")]
    if not tables[0].exists():
        pytest.skip("needs /proc/net/tcp to see that ffmpeg listens")
    for table in tables:
        rows = table.read_text().splitlines()[1:] if table.exists() else []
        for row in rows:
            local, state = row.split()[1], row.split()[3]
            if state == "0A" and int(local.rsplit(":", 1)[1], 16) == port:  # 0A: LISTEN
                return True
    return False


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

    def finish(self, summary: RunSummary) -> None:
        self.finished = True
