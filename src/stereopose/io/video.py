"""Camera sources: video files, image folders and live RTSP/HTTP streams, read in step.

``open_source(spec, name)`` opens one camera: a URL (rtsp, rtsps, http, https, rtmp, udp, tcp) is a
live stream read on its own thread; a folder is a sequence of images; anything else is a video
file. ``CameraSet`` (io.cameraset) reads several cameras together and yields one ``FrameSet``
per time step:

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
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Union

import cv2
import numpy as np

from stereopose.io.looping import PingPong, Seeker
from stereopose.io.source import (
    IMAGE_SUFFIXES,
    STREAM_SCHEMES,
    Clock,
    SourceStats,
    VideoError,
    check_fps,
    is_stream,
    source_name,
)

if TYPE_CHECKING:
    from stereopose.io.packets import PacketRing
    from stereopose.io.stream import LiveStream

__all__ = [
    "IMAGE_SUFFIXES",
    "STREAM_SCHEMES",
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
    """A recorded video file, read frame by frame; t = index / fps.

    loop: played forward, then backward, for ever (io.looping), the index and t increasing;
    `period` frames of it (default: all; a set of cameras plays them in step).
    """

    live = False

    def __init__(
        self,
        path: str | Path,
        name: str | None = None,
        fps: float | None = None,
        *,
        loop: bool = False,
    ) -> None:
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
        self.stats = SourceStats(grabbed=1, decoded=1)
        self.loop = bool(loop)
        self._ended = False
        self._play: PingPong | None = None
        self._seeker: Seeker | None = None
        if self.loop:
            if self.count is None:
                self.cap.release()
                raise VideoError(f"{self.path}: cannot be looped: its number of frames is unknown")
            self._play = PingPong(self.count)
            self._seeker = Seeker(self.cap, first.nbytes, self._short)
            self._seeker.chunk[0], self._seeker.cap_pos, self._first = first, 1, None

    def set_period(self, n: int) -> None:
        """A looped file plays only its first n frames (the set's common length)."""
        if self._play is not None:
            self._play.shrink(min(n, self._play.n))

    def next_time(self) -> float | None:
        """The time of the frame read() or skip() would give next; None once it has ended."""
        return None if self._ended else self.index / self.fps

    def read(self) -> tuple[int, float, np.ndarray] | None:
        """The next frame as (index, t, image), or None at the end."""
        if self._play is not None:
            image = self._looped()
        elif self._first is not None:
            image, self._first = self._first, None
        else:
            ok, image = self.cap.read()
            if not ok or image is None:
                return self._end()
            self.stats.grabbed += 1
            self.stats.decoded += 1
        item = (self.index, self.index / self.fps, image)
        self.index += 1
        self.stats.frames += 1
        return item

    def skip(self) -> bool:
        """Pass over the next frame without decoding it to an image; False at the end."""
        if self._ended:
            return False
        if self._play is not None and self._seeker is not None:
            if not self._seeker.grab(self._play.pos):
                return self.skip()  # the file is shorter than it said: the loop turned back
            self._play.advance()
        elif self._first is not None:
            self._first = None
        elif self.cap.grab():
            self.stats.grabbed += 1
        else:
            self._end()
            return False
        self.index += 1
        self.stats.skipped += 1
        return True

    def _looped(self) -> np.ndarray:
        play, seeker = self._play, self._seeker
        assert play is not None and seeker is not None  # a looped file
        for _ in range(3):  # a short file shrinks the loop once; its frame 0 decoded before
            pos = play.pos
            image = seeker.frame(pos)
            if image is not None:
                self.stats.decoded += 1
                play.advance()
                return image
        raise VideoError(f"{self.path}: stopped decoding while looped")

    def _short(self, n: int) -> None:
        """A looped file decodes only n frames: the loop turns back there."""
        if self._play is not None and n < self._play.n:
            logger.warning(
                "%s: decoding stopped at frame %d of %d (truncated or corrupt); looping %d frames",
                self.path,
                n,
                self._play.n,
                max(n, 1),
            )
            self._play.shrink(n)

    def _end(self) -> None:
        self._ended = True
        if self.count is not None and self.index < self.count:
            logger.warning(
                "%s: decoding stopped at frame %d of %d (truncated or corrupt)",
                self.path,
                self.index,
                self.count,
            )
            self.count = self.index
        return None

    def close(self) -> None:
        self.cap.release()


class ImageFolder:
    """A folder of images in name order (natural order of the numbers in the names).

    loop: played forward, then backward, for ever, as VideoFile's."""

    live = False

    def __init__(
        self,
        path: str | Path,
        name: str | None = None,
        fps: float | None = None,
        *,
        loop: bool = False,
    ) -> None:
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
        self.loop = bool(loop)
        self._play = PingPong(len(self.files)) if self.loop else None

    def set_period(self, n: int) -> None:
        if self._play is not None:
            self._play.shrink(min(n, self._play.n))

    def next_time(self) -> float | None:
        if self._play is None and self.index >= len(self.files):
            return None
        return self.index / self.fps

    def _position(self) -> int | None:
        if self._play is not None:
            pos = self._play.pos
            self._play.advance()
            return pos
        return self.index if self.index < len(self.files) else None

    def read(self) -> tuple[int, float, np.ndarray | None] | None:
        pos = self._position()
        if pos is None:
            return None
        path = self.files[pos]
        image = cv2.imread(str(path), cv2.IMREAD_COLOR)
        if image is None:
            logger.warning("%s: unreadable image skipped", path)
            self.stats.failures += 1
        else:
            self.stats.frames += 1
            self.stats.decoded += 1
        item = (self.index, self.index / self.fps, image)
        self.index += 1
        return item

    def skip(self) -> bool:
        if self._position() is None:
            return False
        self.index += 1
        self.stats.skipped += 1
        return True

    def close(self) -> None:
        pass


def _check_timeouts(open_timeout_s: float, first_frame_timeout_s: float | None) -> None:
    for what, value in (
        ("open_timeout_s", open_timeout_s),
        ("first_frame_timeout_s", first_frame_timeout_s),
    ):
        if value is None and what == "first_frame_timeout_s":
            continue
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise VideoError(f"{what} must be a positive number of seconds, got {value!r}")
        if not (math.isfinite(value) and value > 0):
            raise VideoError(f"{what} must be a positive number of seconds, got {value!r}")


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
    loop: bool = False,
    packets: PacketRing | None = None,
) -> Source:
    """A camera source from a file path, an image folder or a stream URL.

    fps, loop: a recorded source's frame rate (default: its own) and whether it is played for
    ever (forward then backward); clock, notify, open_timeout_s, packets: a live stream's
    (io.stream.LiveStream; packets: kept encoded there, never decoded)."""
    text = str(spec)
    fps = check_fps(fps, f"{text}: fps")
    if is_stream(text):
        from stereopose.io.stream import LiveStream, StreamWaits

        waits = StreamWaits(timeout_s=open_timeout_s)
        return LiveStream(text, name, waits, clock=clock, notify=notify, packets=packets)
    path = Path(text)
    if path.is_dir():
        return ImageFolder(path, name, fps, loop=loop)
    return VideoFile(path, name, fps, loop=loop)


@dataclass
class FrameSet:
    """One time step: each camera's image (None where it has no frame at this step).

    t: the step's time, seconds (recorded: index / fps; live: the newest arrival time of the
    step's frames on the set's clock, strictly increasing from step to step).
    source_frames: each camera's own frame number (live: its count of frames received).
    times: each camera's own time of its frame (recorded: in its file; live: when it arrived,
    seconds on the set's clock), so that a camera lagging behind shows.
    detect: the frames of the cameras that have a detection substream (their own, smaller
    size); a camera without one is detected on its image.
    """

    index: int
    t: float
    images: dict[str, np.ndarray | None]
    source_frames: dict[str, int] = field(default_factory=dict)
    times: dict[str, float] = field(default_factory=dict)
    detect: dict[str, np.ndarray | None] = field(default_factory=dict)


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
                name,
                step.index,
                image.shape,
                image.dtype,
            )
            continue
        usable.append((name, image))
    return usable
