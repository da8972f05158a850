"""An MP4 video written frame by frame (OpenCV's FFmpeg writer, MPEG-4 Part 2, which every
player and browser-side decoder of the project's users opens), opened on its first frame: the
overlay videos and the event clips."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from stereopose.errors import StereoposeError

__all__ = ["FrameWriter"]


class FrameWriter:
    """Frames into the MP4 at `path` at `fps`; the size is the first frame's, and a later frame
    of another size is resized to it. `what` names the video in errors. `close()` releases
    the file (once; later calls do nothing)."""

    def __init__(self, path: str | Path, fps: float, what: str = "the video") -> None:
        self.path, self.fps, self.what = Path(path), float(fps), what
        self.size: tuple[int, int] | None = None
        self.frames = 0
        self._writer: cv2.VideoWriter | None = None

    @property
    def opened(self) -> bool:
        return self._writer is not None

    def write(self, image: np.ndarray) -> None:
        if self._writer is None:
            self.size = (image.shape[1], image.shape[0])
            self._writer = cv2.VideoWriter(
                str(self.path), cv2.VideoWriter.fourcc(*"mp4v"), self.fps, self.size
            )
            if not self._writer.isOpened():
                self._writer = None
                raise StereoposeError(f"{self.path}: cannot write {self.what}")
        elif (image.shape[1], image.shape[0]) != self.size:
            image = cv2.resize(image, self.size)
        self._writer.write(image)
        self.frames += 1

    def close(self) -> None:
        if self._writer is not None:
            self._writer.release()
            self._writer = None
