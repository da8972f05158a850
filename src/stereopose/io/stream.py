"""Live cameras: an RTSP/HTTP stream read on its own thread, newest frame first, reopened with
exponential backoff when it cannot be opened or drops out.

Every wait is bounded: opening and reading use FFmpeg's own timeouts (``timeout_s``), a retry
waits at most ``max_backoff_s``, and ``close()`` waits at most ``JOIN_S`` for the thread (one
stuck inside an open or a read ends by itself within ``timeout_s``; it is a daemon thread). While
a camera does not deliver, why and when it is tried next is logged every ``log_every_s``.

Decoding only what is used: the thread takes every frame that arrives (``grab``: FFmpeg's
demuxing and decoding, which inter-coded video needs for every frame), but converts it to a BGR
image (``retrieve``: the colour conversion and copy, about a third of the cost) only when a
consumer has asked for a frame with ``request()``. So a step that takes every camera's frame
gets the first one to arrive after it asked, and frames no step asked for cost no conversion.
"""

from __future__ import annotations

import logging
import socket
import threading
import time
from dataclasses import dataclass
from urllib.parse import urlsplit

import cv2
import numpy as np

from stereopose.io.packets import PacketRing, StreamFormat
from stereopose.io.source import JOIN_S, Clock, SourceStats, source_name
from stereopose.secrets import redact

logger = logging.getLogger(__name__)

DEFAULT_PORTS = {"rtsp": 554, "rtsps": 322, "http": 80, "https": 443, "rtmp": 1935}


def why_not_open(url: str, timeout_s: float) -> str:
    """A short reason a stream did not open within timeout_s, from one plain TCP connection
    to its server (itself given at most 2 s)."""
    try:
        parts = urlsplit(url)
        host, port = parts.hostname, parts.port or DEFAULT_PORTS.get(parts.scheme.lower())
    except ValueError as e:
        return f"invalid URL ({e})"
    if parts.scheme.lower() == "udp":  # nothing to connect to: packets come, or they do not
        return f"no stream arrived within {timeout_s:g} s"
    if not host or port is None:
        return "the stream did not open"
    try:
        with socket.create_connection((host, port), timeout=min(timeout_s, 2.0)):
            pass
    except socket.gaierror:
        return f"host {host} not found"
    except ConnectionRefusedError:
        return "connection refused"
    except TimeoutError:
        return f"no answer from {host}:{port} within {min(timeout_s, 2.0):g} s"
    except OSError as e:
        return e.strerror or type(e).__name__
    return (
        f"the server accepts connections but no video came within {timeout_s:g} s "
        "(wrong path, or not a video stream)"
    )


def _capture_params(timeout_s: float) -> list[int]:
    """FFmpeg's open and read timeouts, where this OpenCV has them."""
    ms = max(1, int(timeout_s * 1000))
    params = []
    for name in ("CAP_PROP_OPEN_TIMEOUT_MSEC", "CAP_PROP_READ_TIMEOUT_MSEC"):
        if hasattr(cv2, name):
            params += [getattr(cv2, name), ms]
    return params


@dataclass(frozen=True)
class StreamWaits:
    """timeout_s: the most opening or reading waits; backoff_s: the first wait before trying
    again after a loss, doubled up to max_backoff_s; log_every_s: the same problem logged at
    most this often."""

    timeout_s: float = 5.0
    backoff_s: float = 0.5
    max_backoff_s: float = 10.0
    log_every_s: float = 10.0


class LiveStream:
    """A live camera read on its own thread; ``latest()`` gives the newest unread frame.

    When the stream cannot be opened, or frames stop coming for ``timeout_s``, it is reopened
    after ``backoff_s`` seconds, doubling up to ``max_backoff_s``, for as long as the run lasts.
    Each frame carries its arrival time on ``clock`` (seconds since the clock's start); each new
    image sets ``notify`` (an event shared by a set of cameras), if given. The first frame is
    decoded unasked; after it, one frame per ``request()`` (see the module's docstring).
    """

    live = True

    def __init__(
        self,
        url: str,
        name: str | None = None,
        waits: StreamWaits = StreamWaits(),
        *,
        clock: Clock | None = None,
        notify: threading.Event | None = None,
        packets: PacketRing | None = None,
    ) -> None:
        self.url = str(url)
        self.path = self.url
        self.name = name or source_name(self.url)
        self.timeout_s, self.backoff_s = waits.timeout_s, waits.backoff_s
        self.max_backoff_s = waits.max_backoff_s
        self.clock = clock or Clock.now()
        self.log_every_s = waits.log_every_s
        self.fps: float | None = None
        self.count: int | None = None
        self.shape: tuple[int, int] | None = None
        self.stats = SourceStats()
        self.connected = False
        self.problem = "not opened yet"  # why it does not deliver now, for messages
        self._notify = notify
        self.packets = packets  # given: the stream is kept encoded there, never decoded
        self._up = threading.Event()
        self._lock = threading.Lock()
        self._latest: tuple[int, float, np.ndarray] | None = None
        self._seq = 0  # frames grabbed
        self._read_seq = 0
        self._want = threading.Event()  # a consumer asked for the next frame's image
        self._want.set()  # the first frame: its size and a first step without asking
        self.last_frame_at: float | None = None  # monotonic time of the newest frame grabbed
        self._stop = threading.Event()
        self._down_since: float | None = time.monotonic()
        self._logged: tuple[float, str] | None = None  # when and what was last logged
        self._thread = threading.Thread(target=self._run, name=f"camera-{self.name}", daemon=True)
        self._thread.start()

    @property
    def label(self) -> str:
        """The camera's name and URL (password left out), for messages."""
        return f"{self.name} ({redact(self.url)})"

    @property
    def delivered(self) -> bool:
        """Whether a frame has arrived since the stream was created."""
        return self._seq > 0

    def _open(self) -> cv2.VideoCapture | None:
        params = _capture_params(self.timeout_s)
        if self.packets is not None:  # demuxed only: grab() gives the encoded packet
            params += [cv2.CAP_PROP_FORMAT, -1]
        cap = cv2.VideoCapture(self.url, cv2.CAP_FFMPEG, params)
        if cap.isOpened():
            return cap
        cap.release()
        return None

    def _run(self) -> None:
        delay = self.backoff_s
        while not self._stop.is_set():
            cap = self._open()
            if cap is None:
                self._waiting(why_not_open(self.url, self.timeout_s), delay)
            else:
                got_frame = self._read(cap)
                cap.release()
                if self._stop.is_set():
                    break
                if got_frame:
                    delay = self.backoff_s
                    self._lost(delay)
                else:
                    self._waiting(f"opened, but no frame came within {self.timeout_s:g} s", delay)
            if self._stop.wait(delay):
                break
            delay = min(delay * 2, self.max_backoff_s)

    def _read(self, cap: cv2.VideoCapture) -> bool:
        """Grab frames until the stream fails or the run stops, decoding those asked for;
        whether any frame came."""
        fps = cap.get(cv2.CAP_PROP_FPS)
        if 0 < fps < 1000:
            self.fps = float(fps)
        if self.packets is not None:
            return self._keep_packets(cap)
        got_frame = False
        while not self._stop.is_set():
            if not cap.grab():
                break
            now = time.monotonic()
            self.last_frame_at = now
            self.stats.grabbed += 1
            if not got_frame:
                got_frame = True
                self._went_up(now)
            if not self._want.is_set():
                with self._lock:
                    self._seq += 1
                    self.stats.dropped += 1  # arrived while no step wanted a frame
                continue
            ok, image = cap.retrieve()
            if not ok or image is None:
                break
            self._want.clear()
            self.stats.decoded += 1
            with self._lock:
                if self._latest is not None and self._read_seq < self._latest[0]:
                    self.stats.dropped += 1
                self._seq += 1
                self._latest = (self._seq, self.clock.since(now), image)
                self.shape = image.shape[:2]
            if self._notify is not None:
                self._notify.set()
        return got_frame

    def _keep_packets(self, cap: cv2.VideoCapture) -> bool:
        """Grab packets into `packets` until the stream fails or the run stops (no decoding,
        no image ever given out); whether any came."""
        ring = self.packets
        assert ring is not None  # kept encoded: into its ring
        ring.clear()  # a reopened stream starts again from its next keyframe
        w, h = int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT))
        code = int(cap.get(cv2.CAP_PROP_FOURCC)).to_bytes(4, "little")
        fourcc = code.decode("ascii", "replace").strip("\x00 ")
        if w > 0 and h > 0:
            self.shape = (h, w)
            ring.format = StreamFormat(fourcc, self.fps or 25.0, (w, h))
        got_frame = False
        while not self._stop.is_set():
            if not cap.grab():
                break
            now = time.monotonic()
            ok, packet = cap.retrieve()
            if not ok or packet is None:
                break
            self.last_frame_at = now
            self.stats.grabbed += 1
            if not got_frame:
                got_frame = True
                self._went_up(now)
            keyframe = bool(cap.get(cv2.CAP_PROP_LRF_HAS_KEY_FRAME))
            ring.push(self.clock.since(now), keyframe, packet.tobytes())
            with self._lock:
                self._seq += 1
        return got_frame

    def _waiting(self, problem: str, delay: float) -> None:
        """Not delivering: log why and when the next try comes, at most every log_every_s
        (and whenever the reason changes)."""
        self.problem = problem
        now = time.monotonic()
        last = self._logged
        if last is None or now - last[0] >= self.log_every_s or last[1] != problem:
            self._logged = (now, problem)
            logger.warning(
                "waiting for camera %s: %s; retry in %s", self.label, problem, _seconds(delay)
            )

    def _lost(self, delay: float) -> None:
        self.connected = False
        self._up.clear()
        self._down_since = time.monotonic()
        self.stats.failures += 1
        self.problem = f"stream lost (no frame for {self.timeout_s:g} s, or it closed)"
        self._logged = (self._down_since, self.problem)
        logger.warning(
            "camera %s: stream %s lost; reconnecting (backoff %.1f s)",
            self.name,
            redact(self.url),
            delay,
        )

    @property
    def lost(self) -> bool:
        """Whether the stream is known lost: it delivered, then ended or fell silent (or its
        decoder died), and it is not back yet. (Not yet opened is not lost.)"""
        return self._down_since is not None

    def _went_up(self, now: float) -> None:
        if self._down_since is not None:
            self.stats.down_s += now - self._down_since
            self._down_since = None
        if self._logged is not None:  # it was waited for, or lost: say it is back
            self.stats.reconnects += 1
            logger.warning("camera %s: stream %s back", self.name, redact(self.url))
        self._logged = None
        self.problem = ""
        self.connected = True
        self._up.set()

    def request(self) -> None:
        """Ask for the next frame that arrives as an image (``latest()`` then gives it); an
        image decoded before and not read is dropped (counted), so the next one is newer than
        this call."""
        with self._lock:
            if self._latest is not None and self._read_seq < self._latest[0]:
                self._read_seq = self._latest[0]
                self.stats.dropped += 1
        self._want.set()

    def latest(self) -> tuple[int, float, np.ndarray] | None:
        """The newest image not read before as (sequence number: frames received so far,
        arrival time t on the clock, image), or None."""
        with self._lock:
            if self._latest is None or self._latest[0] == self._read_seq:
                return None
            self._read_seq = self._latest[0]
            self.stats.frames += 1
            return self._latest

    def wait_connected(self, timeout: float) -> bool:
        """Wait at most `timeout` seconds for the stream to deliver; whether it does."""
        return self._up.wait(timeout)

    def stop(self) -> None:
        """Ask the thread to stop, without waiting (close() waits)."""
        self._stop.set()

    def close(self, timeout_s: float = JOIN_S) -> None:
        """Stop the thread, waiting for it at most timeout_s (see the module's docstring)."""
        self._stop.set()
        self._thread.join(timeout=timeout_s)
        if self._thread.is_alive():
            logger.debug("camera %s: its thread ends after its open or read times out", self.name)
        if self._down_since is not None:
            self.stats.down_s += time.monotonic() - self._down_since
            self._down_since = None


def _seconds(s: float) -> str:
    return f"{s:.1f} s" if s < 1 else f"{s:.0f} s"
