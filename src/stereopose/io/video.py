"""Camera sources: video files, image folders and live RTSP/HTTP streams, read in step.

``open_source(spec, name)`` opens one camera: a URL (rtsp, rtsps, http, https, rtmp, udp, tcp) is a
live stream read on its own thread; a folder is a sequence of images; anything else is a video
file. ``CameraSet`` reads several cameras together and yields one ``FrameSet`` per time step:

- recorded sources (files, folders) are read as fast as they are consumed, aligned by frame index
  (``sync="index"``) or by time (``sync="time"``: each camera's frame nearest the step's time, from
  its own frame rate), until every camera has ended;
- live streams always give their latest frame (older, unread frames are dropped and counted); a
  camera that drops out is reopened with exponential backoff while the other cameras go on, and
  each loss and recovery is logged.

Errors name the file or URL: a missing, unreadable or corrupt video is a ``VideoError``.
"""

from __future__ import annotations

import logging
import os
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Union

import cv2
import numpy as np

from stereopose.io.source import (
    IMAGE_SUFFIXES,
    STREAM_SCHEMES,
    SourceStats,
    VideoError,
    is_stream,
    source_name,
)

if TYPE_CHECKING:
    from stereopose.io.stream import LiveStream

__all__ = [
    "IMAGE_SUFFIXES",
    "STREAM_SCHEMES",
    "CameraSet",
    "FrameSet",
    "ImageFolder",
    "SourceStats",
    "VideoError",
    "VideoFile",
    "is_stream",
    "open_source",
    "source_name",
    "usable_images",
]

logger = logging.getLogger(__name__)

# FFmpeg's and OpenCV's own messages on a bad file go to stderr; the errors raised here say it.
os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "-8")
cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_ERROR)


class VideoFile:
    """A recorded video file, read frame by frame; t = index / fps."""

    live = False

    def __init__(self, path: str | Path, name: str | None = None, fps: float | None = None):
        self.path = Path(path)
        self.name = name or self.path.stem
        if not self.path.is_file():
            raise VideoError(f"{self.path}: video file not found")
        self.cap = cv2.VideoCapture(str(self.path), cv2.CAP_FFMPEG)
        if not self.cap.isOpened():
            raise VideoError(f"{self.path}: cannot open the video (unknown format or corrupt)")
        ok, first = self.cap.read()
        if not ok or first is None or first.size == 0:
            self.cap.release()
            raise VideoError(f"{self.path}: no decodable frame (corrupt or empty video)")
        self._first: np.ndarray | None = first
        self.shape = first.shape[:2]
        file_fps = self.cap.get(cv2.CAP_PROP_FPS)
        self.fps = float(fps or (file_fps if 0 < file_fps < 1000 else 25.0))
        count = int(self.cap.get(cv2.CAP_PROP_FRAME_COUNT))
        self.count: int | None = count if count > 0 else None
        self.index = 0
        self.stats = SourceStats()

    def read(self) -> tuple[int, float, np.ndarray] | None:
        """The next frame as (index, t, image), or None at the end."""
        if self._first is not None:
            image, self._first = self._first, None
        else:
            ok, image = self.cap.read()
            if not ok or image is None:
                if self.count is not None and self.index < self.count:
                    logger.warning(
                        "%s: decoding stopped at frame %d of %d (truncated or corrupt)",
                        self.path,
                        self.index,
                        self.count,
                    )
                    self.count = self.index
                return None
        item = (self.index, self.index / self.fps, image)
        self.index += 1
        self.stats.frames += 1
        return item

    def close(self) -> None:
        self.cap.release()


class ImageFolder:
    """A folder of images in name order (natural order of the numbers in the names)."""

    live = False

    def __init__(self, path: str | Path, name: str | None = None, fps: float | None = None):
        self.path = Path(path)
        self.name = name or self.path.name
        self.files = sorted(
            (p for p in self.path.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES),
            key=_natural,
        )
        if not self.files:
            raise VideoError(f"{self.path}: no images ({', '.join(IMAGE_SUFFIXES)}) in the folder")
        self.fps = float(fps or 25.0)
        self.count: int | None = len(self.files)
        self.index = 0
        self.shape: tuple[int, int] | None = None
        self.stats = SourceStats()

    def read(self) -> tuple[int, float, np.ndarray | None] | None:
        if self.index >= len(self.files):
            return None
        path = self.files[self.index]
        image = cv2.imread(str(path), cv2.IMREAD_COLOR)
        if image is None:
            logger.warning("%s: unreadable image skipped", path)
            self.stats.failures += 1
        else:
            self.stats.frames += 1
        item = (self.index, self.index / self.fps, image)
        self.index += 1
        return item

    def close(self) -> None:
        pass


def _natural(path: Path) -> list[object]:
    import re

    return [int(t) if t.isdigit() else t for t in re.split(r"(\d+)", path.name)]


Source = Union[VideoFile, ImageFolder, "LiveStream"]


def open_source(spec: str | Path, name: str | None = None, fps: float | None = None) -> Source:
    """A camera source from a file path, an image folder or a stream URL."""
    text = str(spec)
    if is_stream(text):
        from stereopose.io.stream import LiveStream

        return LiveStream(text, name)
    path = Path(text)
    if path.is_dir():
        return ImageFolder(path, name, fps)
    return VideoFile(path, name, fps)


@dataclass
class FrameSet:
    """One time step: each camera's image (None where it has no frame at this step).

    t: the step's time, seconds (recorded: index / fps; live: since the run started).
    source_frames: each camera's own frame number (live: its count of frames received).
    times: each camera's own time of its frame (recorded: in its file; live: when it arrived,
    seconds since the run started), so that a camera lagging behind shows.
    """

    index: int
    t: float
    images: dict[str, np.ndarray | None]
    source_frames: dict[str, int] = field(default_factory=dict)
    times: dict[str, float] = field(default_factory=dict)


def usable_images(step: FrameSet) -> list[tuple[str, np.ndarray]]:
    """The step's (camera, image) pairs with a usable BGR image; an empty or malformed frame is
    logged and left out (that camera has no frame at this step)."""
    usable = []
    for name, image in step.images.items():
        if image is None:
            continue
        if image.ndim != 3 or image.shape[2] != 3 or image.size == 0 or image.dtype != np.uint8:
            logger.warning(
                "camera %s: frame %d is not a BGR image (shape %s, %s); skipped",
                name, step.index, image.shape, image.dtype,
            )  # fmt: skip
            continue
        usable.append((name, image))
    return usable


class CameraSet:
    """Several cameras read in step; iterate for FrameSets; close() ends every reader."""

    def __init__(
        self,
        specs: Sequence[str | Path],
        names: Sequence[str] | None = None,
        sync: str = "index",
        fps: float | None = None,
        max_frames: int | None = None,
    ) -> None:
        if not specs:
            raise VideoError("no camera sources given")
        if names is not None and len(names) != len(specs):
            raise VideoError(f"{len(names)} camera names for {len(specs)} sources")
        names = list(names) if names is not None else [source_name(str(s)) for s in specs]
        if len(set(names)) != len(names):
            raise VideoError(f"camera names must be unique, got {', '.join(names)}; use --names")
        if sync not in ("index", "time"):
            raise VideoError(f"sync must be 'index' or 'time', got {sync!r}")
        self.sync, self.max_frames = sync, max_frames
        self.sources: list[Source] = []
        try:
            for spec, name in zip(specs, names, strict=False):
                self.sources.append(open_source(spec, name, fps))
        except BaseException:
            self.close()
            raise
        self.live = any(s.live for s in self.sources)
        if self.live and not all(s.live for s in self.sources):
            self.close()
            raise VideoError("mixing live streams with recorded files is not supported")
        rates = [s.fps for s in self.sources if s.fps]
        self.fps = float(fps or (rates[0] if rates else 25.0))
        self._ended: set[str] = set()

    @property
    def names(self) -> list[str]:
        return [s.name for s in self.sources]

    @property
    def count(self) -> int | None:
        """Number of steps of a recorded set (longest camera), or None if unknown or live."""
        if self.live:
            return None
        counts = [s.count for s in self.sources]
        if any(c is None for c in counts):
            return None
        n = (
            max(counts)
            if self.sync == "index"
            else max(
                int(np.ceil(c / s.fps * self.fps))
                for c, s in zip(counts, self.sources, strict=False)
            )
        )
        return min(n, self.max_frames) if self.max_frames else n

    def __iter__(self) -> Iterator[FrameSet]:
        return self._live() if self.live else self._recorded()

    def _recorded(self) -> Iterator[FrameSet]:
        half = 0.5 / self.fps
        nxt = {s.name: s.read() for s in self.sources} if self.sync == "time" else {}
        step = 0
        while self.max_frames is None or step < self.max_frames:
            t = step / self.fps
            images: dict[str, np.ndarray | None] = {}
            frames: dict[str, int] = {}
            times: dict[str, float] = {}
            for s in self.sources:
                item = None
                if s.name in self._ended:
                    pass
                elif self.sync == "index":
                    item = s.read()
                    if item is None:
                        self._end(s)
                else:  # the last of this camera's frames with time in [t - half, t + half)
                    while nxt[s.name] is not None and nxt[s.name][1] < t + half:
                        item = nxt[s.name]
                        nxt[s.name] = s.read()
                    if nxt[s.name] is None:
                        self._end(s)
                    if item is not None and item[1] < t - half:
                        item = None
                images[s.name] = None if item is None else item[2]
                if item is not None and item[2] is not None:
                    frames[s.name] = item[0]
                    times[s.name] = item[1]
            if not frames and len(self._ended) == len(self.sources):
                return
            yield FrameSet(step, t, images, frames, times)
            step += 1

    def _end(self, s: Source) -> None:
        self._ended.add(s.name)
        logger.info("camera %s: end of %s after %d frames", s.name, s.path, s.stats.frames)

    def _live(self) -> Iterator[FrameSet]:
        start = time.monotonic()
        step = 0
        period = 1.0 / self.fps
        while self.max_frames is None or step < self.max_frames:
            images: dict[str, np.ndarray | None] = {}
            frames: dict[str, int] = {}
            times: dict[str, float] = {}
            for s in self.sources:
                got = s.latest()
                images[s.name] = None if got is None else got[2]
                if got is not None:
                    frames[s.name] = got[0]
                    times[s.name] = got[1] - start
            if not frames:  # nothing new from any camera: wait a little
                time.sleep(min(period, 0.01))
                continue
            yield FrameSet(step, time.monotonic() - start, images, frames, times)
            step += 1

    def stats(self) -> dict[str, SourceStats]:
        return {s.name: s.stats for s in self.sources}

    def close(self) -> None:
        for s in self.sources:
            s.close()

    def __enter__(self) -> CameraSet:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
