"""Recorded files played at a detection node as live cameras are: on the wall clock.

Cameras on several machines see the same moment at the same time; their frames are matched
by capture time. Files read each at its own node's pace would not be: two nodes would show
different moments of the recording at once. So a node plays its files on the wall clock: at
the time T (seconds since 1970) a camera shows the frame at ``floor(T * fps)`` of its
recording, played forward then backward for ever (io.looping's order) when it loops, from the
node's start once when it does not. Every node plays the same frame at the same T whenever it
was started, as synchronised cameras would.

Steps are taken on a grid of the wall clock (every 1 / detect_fps s, or every frame): each
step shows every camera's frame of the newest grid time already come (the next one is waited
for once that has been shown); grid times the node was too busy for are passed over (counted
in `skipped`), as a live camera's frames are. Each
camera's frames are decoded once at the start and kept as JPEG (quality 95) in memory, at
most MAX_BYTES per camera, so any frame is one JPEG decode away.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Iterator, Mapping
from dataclasses import dataclass

import cv2
import numpy as np

from stereopose.errors import StereoposeError
from stereopose.io.video import FrameSet

logger = logging.getLogger(__name__)

MAX_BYTES = 512 * 2**20
JPEG_QUALITY = 95


class PacedError(StereoposeError):
    """A recorded camera that cannot be played at a node."""


@dataclass
class PacedStats:
    skipped: int = 0  # grid times passed over (the node was busy)


def ping_pong(index: int, n: int) -> int:
    """The position in a recording of n frames of frame `index` of its endless forward then
    backward play: 0, 1, ..., n-1, n-2, ..., 1, 0, 1, ..."""
    if n <= 1:
        return 0
    period = 2 * (n - 1)
    i = index % period
    return i if i < n else period - i


class PacedCamera:
    """One recorded file, decoded once and kept as JPEG."""

    def __init__(self, name: str, path: str, loop: bool, max_bytes: int = MAX_BYTES) -> None:
        self.name, self.path, self.loop = name, path, loop
        cap = cv2.VideoCapture(path)
        if not cap.isOpened():
            raise PacedError(f"camera {name}: cannot open {path} as a video")
        try:
            fps = float(cap.get(cv2.CAP_PROP_FPS) or 0.0)
            if not (math.isfinite(fps) and 0 < fps <= 1000):
                raise PacedError(f"camera {name}: {path} has no frame rate")
            self.fps = fps
            self.frames: list[bytes] = []
            size = 0
            while True:
                ok, image = cap.read()
                if not ok:
                    break
                ok, jpeg = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
                if not ok:
                    raise PacedError(f"camera {name}: cannot keep frame {len(self.frames)}")
                self.frames.append(jpeg.tobytes())
                size += len(self.frames[-1])
                if size > max_bytes:
                    raise PacedError(
                        f"camera {name}: {path} is too long to be played at a "
                        f"node (more than {max_bytes >> 20} MiB as JPEG after "
                        f"{len(self.frames)} frames); cut it"
                    )
        finally:
            cap.release()
        if not self.frames:
            raise PacedError(f"camera {name}: {path} has no readable frame")
        self.bytes = size
        first = self.image(0)
        self.shape = first.shape

    def position(self, t: float, start: float) -> int | None:
        """Its frame at wall time t (None: a file played once, over)."""
        n = len(self.frames)
        if self.loop:
            return ping_pong(math.floor(t * self.fps), n)
        i = math.floor((t - start) * self.fps)
        return i if 0 <= i < n else None

    def image(self, pos: int) -> np.ndarray:
        image = cv2.imdecode(np.frombuffer(self.frames[pos], np.uint8), cv2.IMREAD_COLOR)
        if image is None:
            raise PacedError(f"camera {self.name}: frame {pos} cannot be decoded")
        return image


class PacedFiles:
    """Recorded cameras on the wall clock (see the module): iterate for FrameSets whose t is
    the capture time, seconds since 1970. rate: grid times per second (default: the highest
    of the files' frame rates). end() stops an iteration waiting for its next grid time."""

    def __init__(
        self,
        cameras: Mapping[str, tuple[str, bool]],
        rate: float | None = None,
        max_bytes: int = MAX_BYTES,
    ) -> None:
        self.cameras = {
            name: PacedCamera(name, path, loop, max_bytes) for name, (path, loop) in cameras.items()
        }
        own = max(c.fps for c in self.cameras.values())
        self.fps = own
        self.rate = min(float(rate), own) if rate else own
        self.stats = {name: PacedStats() for name in self.cameras}
        self.start = time.time()
        self._end = threading.Event()

    @property
    def names(self) -> list[str]:
        return list(self.cameras)

    def end(self) -> None:
        self._end.set()

    def __iter__(self) -> Iterator[FrameSet]:
        g = 1.0 / self.rate
        last: int | None = None
        while not self._end.is_set():
            # the newest grid time already come, as a live camera's newest frame; the next
            # one waited for when it has been shown
            k = math.floor(time.time() / g)
            if last is not None and k <= last:
                k = last + 1
            if last is not None and k > last + 1:
                for s in self.stats.values():
                    s.skipped += k - last - 1
            if self._end.wait(max(0.0, k * g - time.time())):
                return
            t = k * g
            images: dict[str, np.ndarray | None] = {}
            frames: dict[str, int] = {}
            for name, cam in self.cameras.items():
                pos = cam.position(t, self.start)
                images[name] = None if pos is None else cam.image(pos)
                if pos is not None:
                    frames[name] = pos
            if not frames:
                logger.info("every recorded camera of this node has ended")
                return
            last = k
            yield FrameSet(k, t, images, frames, {n: t for n in frames})
