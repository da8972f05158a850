"""The console's camera pictures: each camera's newest image drawn with its skeletons and ids
(viz.overlay), kept as a JPEG.

The frame loop only offers frames (`offer`): a few times a second a frame's images go into a
queue of SNAPSHOT_QUEUE frames (full: the frame is dropped and counted). The encoder's thread
draws and encodes them: at `snapshot_hz` while someone looks at the pictures (a picture asked
for within WATCHED_S), at IDLE_SNAPSHOT_HZ otherwise. A picture's longest side is at least
SNAPSHOT_MIN_SIDE pixels (up to the frame's own size), so the ids drawn on a small detection
substream can still be read when the picture is enlarged.
"""

from __future__ import annotations

import contextlib
import logging
import math
import queue
import threading
import time
from collections.abc import Callable, Iterable, Mapping
from datetime import UTC, datetime
from typing import TYPE_CHECKING

import cv2

from stereopose.io.sinks.base import FrameResult

if TYPE_CHECKING:
    from stereopose.types import People3D

__all__ = [
    "IDLE_SNAPSHOT_HZ",
    "SNAPSHOT_MIN_SIDE",
    "SNAPSHOT_QUEUE",
    "PictureEncoder",
    "picture_scale",
]

logger = logging.getLogger(__name__)

SNAPSHOT_QUEUE = 2
IDLE_SNAPSHOT_HZ = 0.5
SNAPSHOT_MIN_SIDE = 640
WATCHED_S = 10.0  # a snapshot asked for within this long: someone is looking


def picture_scale(shape: tuple[int, ...], scale: float) -> float:
    """The scale of a frame of `shape` (height, width, ...) in its picture: `scale`, or more
    (never above the frame's own size) so the longest side has SNAPSHOT_MIN_SIDE pixels."""
    longest = max(int(shape[0]), int(shape[1]), 1)
    return max(float(scale), min(1.0, SNAPSHOT_MIN_SIDE / longest))


class PictureEncoder:
    """See the module. cameras: the names drawn; draw(camera, image, people2d, people3d,
    scale, label) -> the picture; clock(): monotonic seconds (injectable)."""

    def __init__(
        self,
        cameras: Iterable[str],
        draw: Callable,
        *,
        snapshot_hz: float = 3.0,
        snapshot_scale: float = 0.5,
        jpeg_quality: int = 75,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.cameras = frozenset(cameras)
        self.draw, self.clock = draw, clock
        self.snapshot_hz, self.snapshot_scale = snapshot_hz, snapshot_scale
        self.jpeg_quality = jpeg_quality
        self._lock = threading.Lock()
        self._snapshots: dict[str, tuple[bytes, float]] = {}
        self.queue: queue.Queue = queue.Queue(SNAPSHOT_QUEUE)
        self._snap_at = -math.inf
        self._watched_at = -math.inf
        self.snapshots_dropped = self.snapshots_made = self.snapshot_errors = 0
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    # -- the frame loop's side ------------------------------------------------------------

    def offer(self, frame: FrameResult, wall_start: float) -> None:
        """The frame's images for the pictures when one is due (quick, never blocks)."""
        now = self.clock()
        watched = now - self._watched_at <= WATCHED_S
        hz = self.snapshot_hz if watched else IDLE_SNAPSHOT_HZ
        if hz <= 0 or now - self._snap_at < 1.0 / hz:
            return
        self._snap_at = now
        item = (
            wall_start + float(frame.t),
            dict(frame.images or {}),  # (the console offers frames with images only)
            dict(frame.people2d),
            frame.people3d,
        )
        try:
            self.queue.put_nowait(item)
        except queue.Full:
            self.snapshots_dropped += 1

    # -- the encoder's thread -------------------------------------------------------------

    def start(self) -> None:
        self._thread = threading.Thread(target=self._run, name="console-snapshots", daemon=True)
        self._thread.start()

    def close(self, timeout_s: float) -> None:
        self._stop.set()
        with contextlib.suppress(queue.Full):
            self.queue.put_nowait(None)
        if self._thread is not None:
            self._thread.join(timeout_s)

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                item = self.queue.get(timeout=0.5)
            except queue.Empty:
                continue
            if item is None:
                return
            self._encode(*item)

    def _encode(
        self, wall_t: float, images: Mapping, people2d: Mapping, people3d: People3D
    ) -> None:
        stamp = datetime.fromtimestamp(wall_t, UTC).strftime("%H:%M:%S")
        for camera, image in images.items():
            if image is None or camera not in self.cameras:
                continue
            try:
                scale = picture_scale(image.shape, self.snapshot_scale)
                picture = self.draw(
                    camera, image, people2d.get(camera), people3d, scale, f"{camera} {stamp}"
                )
                quality = [cv2.IMWRITE_JPEG_QUALITY, self.jpeg_quality]
                ok, buf = cv2.imencode(".jpg", picture, quality)
            except Exception:  # a bad frame must not stop the pictures
                ok, buf = False, None
                logger.debug("console: camera %s: snapshot not drawn", camera, exc_info=True)
            if not ok or buf is None:
                self.snapshot_errors += 1
                continue
            with self._lock:
                self._snapshots[camera] = (buf.tobytes(), wall_t)
            self.snapshots_made += 1

    # -- the web side's reads --------------------------------------------------------------

    def snapshot(self, camera: str) -> tuple[bytes, float] | None:
        """The camera's newest picture (JPEG, its wall time); None before one. Asking makes
        the pictures come at snapshot_hz for WATCHED_S."""
        self._watched_at = self.clock()
        with self._lock:
            return self._snapshots.get(camera)

    def figures(self) -> dict[str, int]:
        return {
            "snapshots_made": self.snapshots_made,
            "snapshots_dropped": self.snapshots_dropped,
            "snapshot_errors": self.snapshot_errors,
        }
