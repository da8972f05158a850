"""Live cameras: an RTSP/HTTP stream read on its own thread, newest frame first, reopened with
exponential backoff when it drops out."""

from __future__ import annotations

import logging
import threading
import time

import cv2
import numpy as np

from stereopose.io.source import SourceStats, source_name

logger = logging.getLogger(__name__)


class LiveStream:
    """A live camera read on its own thread; ``latest()`` gives the newest unread frame.

    When the connection fails or frames stop coming for ``timeout_s``, the stream is reopened
    after ``backoff_s`` seconds, doubling up to ``max_backoff_s``, for as long as the run lasts.
    """

    live = True

    def __init__(
        self,
        url: str,
        name: str | None = None,
        timeout_s: float = 5.0,
        backoff_s: float = 0.5,
        max_backoff_s: float = 10.0,
    ) -> None:
        self.url = str(url)
        self.path = self.url
        self.name = name or source_name(self.url)
        self.timeout_s, self.backoff_s, self.max_backoff_s = timeout_s, backoff_s, max_backoff_s
        self.fps: float | None = None
        self.count: int | None = None
        self.shape: tuple[int, int] | None = None
        self.stats = SourceStats()
        self.connected = False
        self._lock = threading.Lock()
        self._latest: tuple[int, float, np.ndarray] | None = None
        self._seq = 0
        self._read_seq = 0
        self._stop = threading.Event()
        self._down_since: float | None = time.monotonic()
        self._thread = threading.Thread(target=self._run, name=f"camera-{self.name}", daemon=True)
        self._thread.start()

    def _open(self) -> cv2.VideoCapture | None:
        ms = int(self.timeout_s * 1000)
        cap = cv2.VideoCapture(
            self.url,
            cv2.CAP_FFMPEG,
            [cv2.CAP_PROP_OPEN_TIMEOUT_MSEC, ms, cv2.CAP_PROP_READ_TIMEOUT_MSEC, ms],
        )
        if cap.isOpened():
            return cap
        cap.release()
        return None

    def _run(self) -> None:
        delay = self.backoff_s
        first = True
        while not self._stop.is_set():
            cap = self._open()
            if cap is None:
                if first:
                    logger.warning("camera %s: cannot open %s; retrying", self.name, self.url)
                first = False
                self._stop.wait(delay)
                delay = min(delay * 2, self.max_backoff_s)
                continue
            fps = cap.get(cv2.CAP_PROP_FPS)
            if 0 < fps < 1000:
                self.fps = float(fps)
            got_frame = False
            while not self._stop.is_set():
                ok, image = cap.read()
                if not ok or image is None:
                    break
                now = time.monotonic()
                if not got_frame:
                    got_frame = True
                    delay = self.backoff_s
                    self._went_up(now, first)
                with self._lock:
                    if self._latest is not None and self._read_seq < self._seq:
                        self.stats.dropped += 1
                    self._seq += 1
                    self._latest = (self._seq, now, image)
                    self.shape = image.shape[:2]
            cap.release()
            first = False
            if self._stop.is_set():
                break
            if self.connected:
                self.connected = False
                self._down_since = time.monotonic()
                self.stats.failures += 1
                logger.warning(
                    "camera %s: stream %s lost; reconnecting (backoff %.1f s)",
                    self.name,
                    self.url,
                    delay,
                )
            self._stop.wait(delay)
            delay = min(delay * 2, self.max_backoff_s)

    def _went_up(self, now: float, first: bool) -> None:
        if self._down_since is not None:
            self.stats.down_s += now - self._down_since
            self._down_since = None
        if not first or self.stats.failures:
            self.stats.reconnects += 1
            logger.warning("camera %s: stream %s back", self.name, self.url)
        self.connected = True

    def latest(self) -> tuple[int, float, np.ndarray] | None:
        """The newest frame not read before as (sequence number, monotonic time, image)."""
        with self._lock:
            if self._latest is None or self._latest[0] == self._read_seq:
                return None
            self._read_seq = self._latest[0]
            self.stats.frames += 1
            return self._latest

    def wait_connected(self, timeout: float) -> bool:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if self.connected:
                return True
            time.sleep(0.02)
        return self.connected

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=self.timeout_s + 1)
        if self._down_since is not None:
            self.stats.down_s += time.monotonic() - self._down_since
            self._down_since = None
