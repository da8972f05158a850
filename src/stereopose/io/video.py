"""Camera sources: video files, image folders and live RTSP/HTTP streams, read in step.

``open_source(spec, name)`` opens one camera: a URL (rtsp, rtsps, http, https, rtmp, udp, tcp) is a
live stream read on its own thread; a folder is a sequence of images; anything else is a video
file. ``CameraSet`` reads several cameras together and yields one ``FrameSet`` per time step:

- recorded sources (files, folders) are read as fast as they are consumed, aligned by frame index
  (``sync="index"``) or by time (``sync="time"``: each camera's frame nearest the step's time, from
  its own frame rate), until every camera has ended;
- live streams always give their latest frame (older, unread frames are dropped and counted); a
  camera that cannot be opened or drops out is retried with exponential backoff while the other
  cameras go on, and why it does not deliver is logged periodically. Each live frame carries its
  arrival time on the set's clock (seconds since the set was opened; ``clock.start_epoch`` maps
  it to wall-clock time), and a step's t is the newest arrival among its frames, strictly
  increasing. Opening a set of live cameras waits until one of them delivers a frame: if none
  does within ``first_frame_timeout_s``, a ``VideoError`` names every camera and why it did not
  deliver (so nothing is written for a run that never sees a frame).

Errors name the file or URL: a missing, unreadable or corrupt video is a ``VideoError``; so is a
frame rate that is not a finite positive number (times would never advance).
"""

from __future__ import annotations

import logging
import math
import os
import threading
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Union

import cv2
import numpy as np

from stereopose.io.source import (
    IMAGE_SUFFIXES,
    JOIN_S,
    STREAM_SCHEMES,
    Clock,
    SourceStats,
    VideoError,
    check_fps,
    is_stream,
    source_name,
)

if TYPE_CHECKING:
    from stereopose.io.stream import LiveStream

__all__ = [
    "IMAGE_SUFFIXES",
    "STREAM_SCHEMES",
    "CameraSet",
    "Clock",
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
        fps = check_fps(fps, f"{self.path}: fps")
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
        fps = check_fps(fps, f"{self.path}: fps")
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


def _check_timeouts(open_timeout_s: float, first_frame_timeout_s: float | None) -> None:
    for what, value in (("open_timeout_s", open_timeout_s),
                        ("first_frame_timeout_s", first_frame_timeout_s)):  # fmt: skip
        if value is None and what == "first_frame_timeout_s":
            continue
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise VideoError(f"{what} must be a positive number of seconds, got {value!r}")
        if not (math.isfinite(value) and value > 0):
            raise VideoError(f"{what} must be a positive number of seconds, got {value!r}")


def _after(s: Source, t: float, item: tuple | None) -> tuple | None:
    """A recorded camera's next frame, None (its end) when its time does not come after `t`:
    time alignment then could not advance past it."""
    if item is None or item[1] > t:
        return item
    logger.warning(
        "camera %s: frame %d's time %r does not come after %r; taken as its end",
        s.name, item[0], item[1], t,
    )  # fmt: skip
    return None


def _natural(path: Path) -> list[object]:
    import re

    return [int(t) if t.isdigit() else t for t in re.split(r"(\d+)", path.name)]


Source = Union[VideoFile, ImageFolder, "LiveStream"]


def open_source(
    spec: str | Path,
    name: str | None = None,
    fps: float | None = None,
    *,
    clock: Clock | None = None,
    notify: threading.Event | None = None,
    open_timeout_s: float = 5.0,
) -> Source:
    """A camera source from a file path, an image folder or a stream URL.

    fps: the frame rate of a recorded source (default: its own); clock, notify, open_timeout_s:
    a live stream's (io.stream.LiveStream)."""
    text = str(spec)
    fps = check_fps(fps, f"{text}: fps")
    if is_stream(text):
        from stereopose.io.stream import LiveStream

        return LiveStream(text, name, open_timeout_s, clock=clock, notify=notify)
    path = Path(text)
    if path.is_dir():
        return ImageFolder(path, name, fps)
    return VideoFile(path, name, fps)


@dataclass
class FrameSet:
    """One time step: each camera's image (None where it has no frame at this step).

    t: the step's time, seconds (recorded: index / fps; live: the newest arrival time of the
    step's frames on the set's clock, strictly increasing from step to step).
    source_frames: each camera's own frame number (live: its count of frames received).
    times: each camera's own time of its frame (recorded: in its file; live: when it arrived,
    seconds on the set's clock), so that a camera lagging behind shows.
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
    """Several cameras read in step; iterate for FrameSets; close() ends every reader.

    open_timeout_s: a live stream's open and read timeout; first_frame_timeout_s: how long
    opening live cameras waits for the first frame of any of them (None: for ever; Ctrl-C
    ends the wait). clock: the live frames' time origin, read when the set is created.
    """

    def __init__(
        self,
        specs: Sequence[str | Path],
        names: Sequence[str] | None = None,
        sync: str = "index",
        fps: float | None = None,
        max_frames: int | None = None,
        *,
        open_timeout_s: float = 5.0,
        first_frame_timeout_s: float | None = 30.0,
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
        fps = check_fps(fps, "fps (time steps per second)")
        _check_timeouts(open_timeout_s, first_frame_timeout_s)
        if max_frames is not None and max_frames < 0:
            raise VideoError(f"max_frames must be at least 0, got {max_frames}")
        self.sync, self.max_frames = sync, max_frames
        self.first_frame_timeout_s = first_frame_timeout_s
        self.clock = Clock.now()
        self._fresh = threading.Event()  # set by a live camera at each new frame
        self.sources: list[Source] = []
        try:
            for spec, name in zip(specs, names, strict=False):
                self.sources.append(
                    open_source(spec, name, fps, clock=self.clock, notify=self._fresh,
                                open_timeout_s=open_timeout_s)
                )  # fmt: skip
        except BaseException:
            self.close()
            raise
        self.live = any(s.live for s in self.sources)
        if self.live and not all(s.live for s in self.sources):
            self.close()
            raise VideoError("mixing live streams with recorded files is not supported")
        if self.live:
            try:
                self._wait_first_frame()
            except BaseException:  # the error, or Ctrl-C: no camera thread is left running
                self.close()
                raise
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
        nxt = {}
        if self.sync == "time":
            nxt = {s.name: _after(s, -math.inf, s.read()) for s in self.sources}
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
                        nxt[s.name] = _after(s, item[1], s.read())
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
        step = 0
        last_t = -math.inf
        while self.max_frames is None or step < self.max_frames:
            self._fresh.clear()  # before reading, so that a frame arriving after is waited for
            images: dict[str, np.ndarray | None] = {}
            frames: dict[str, int] = {}
            times: dict[str, float] = {}
            for s in self.sources:
                got = s.latest()
                images[s.name] = None if got is None else got[2]
                if got is not None:
                    frames[s.name] = got[0]
                    times[s.name] = got[1]
            if not frames:  # nothing new from any camera: wait for one, a bounded while
                self._check_first_frame()
                self._fresh.wait(0.25)
                continue
            # strictly increasing, also when a camera's frame arrived just before the last step's
            last_t = max(max(times.values()), last_t + 1e-4)
            yield FrameSet(step, last_t, images, frames, times)
            step += 1

    def _wait_first_frame(self) -> None:
        """Wait until a live camera delivers, or first_frame_timeout_s passes (VideoError)."""
        while not any(s.delivered for s in self.sources):
            self._check_first_frame()
            self._fresh.wait(0.25)
        logger.info("cameras opened; first frame after %.1f s", time.monotonic() - self.clock.start)

    def _check_first_frame(self) -> None:
        """A VideoError naming every camera once first_frame_timeout_s has passed since the
        set was opened without any camera delivering a frame."""
        limit = self.first_frame_timeout_s
        if limit is None or any(s.delivered for s in self.sources):
            return
        if time.monotonic() - self.clock.start < limit:
            return
        why = "; ".join(f"{s.label}: {s.problem}" for s in self.sources)
        raise VideoError(
            f"no camera delivered a frame within {limit:g} s ({why}); "
            "a run's [input] first_frame_timeout_s sets how long to wait"
        )

    def stats(self) -> dict[str, SourceStats]:
        return {s.name: s.stats for s in self.sources}

    def close(self) -> None:
        """Close every camera; live ones are all stopped first, then waited for together, at
        most JOIN_S in all."""
        live = [s for s in self.sources if s.live]
        for s in live:
            s.stop()
        deadline = time.monotonic() + (JOIN_S if live else 0.0)
        for s in self.sources:
            if s.live:
                s.close(max(0.0, deadline - time.monotonic()))
            else:
                s.close()

    def __enter__(self) -> CameraSet:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
