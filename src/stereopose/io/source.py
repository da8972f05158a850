"""What every camera source shares: the names of sources, their statistics, their error.

Recorded sources (io.video) and live streams (io.stream) both build on this module.
"""

from __future__ import annotations

import math
import numbers
import time
from dataclasses import dataclass
from pathlib import Path
from urllib.parse import urlsplit

from stereopose.checks import FPS_MAX, FPS_MIN
from stereopose.errors import StereoposeError

STREAM_SCHEMES = ("rtsp://", "rtsps://", "http://", "https://", "rtmp://", "udp://", "tcp://")
JOIN_S = 1.0  # the longest a live camera's close() waits for its thread (one set's, all together)
IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff", ".webp")


class VideoError(StereoposeError):
    """A camera source is missing, unreadable or corrupt."""


def check_fps(fps: float | None, what: str) -> float | None:
    """A frame rate given by the user: None, or a number in [FPS_MIN, FPS_MAX] (a VideoError
    naming `what` otherwise): at 0, below 0 or NaN times would never advance, and at a huge
    rate aligning cameras by time would take for ever."""
    if fps is None:
        return None
    ok = not isinstance(fps, bool) and isinstance(fps, numbers.Real) and math.isfinite(fps)
    if not (ok and FPS_MIN <= fps <= FPS_MAX):
        raise VideoError(f"{what} must be a number from {FPS_MIN:g} to {FPS_MAX:g}, got {fps!r}")
    return float(fps)


@dataclass(frozen=True)
class Clock:
    """A run's time origin for live cameras: a frame grabbed at monotonic time m has
    t = m - start seconds; wall-clock time is start_epoch + t (start_epoch: seconds since 1970,
    read at the same instant as start)."""

    start: float
    start_epoch: float

    @classmethod
    def now(cls) -> Clock:
        return cls(time.monotonic(), time.time())

    def since(self, monotonic: float) -> float:
        return monotonic - self.start


def is_stream(spec: str) -> bool:
    return str(spec).lower().startswith(STREAM_SCHEMES)


def source_name(spec: str) -> str:
    """Default camera name: the file or folder stem; for a URL, its last path part."""
    if is_stream(spec):
        try:
            parts = urlsplit(str(spec))
            host = parts.hostname
        except ValueError:  # malformed (an unclosed [ipv6 host, say): FFmpeg will say so
            return "stream"
        tail = parts.path.rstrip("/").rsplit("/", 1)[-1].rsplit(".", 1)[0]
        return tail or host or "stream"  # no path: the host (rtsp://10.0.0.5/)
    return Path(spec).stem


@dataclass
class SourceStats:
    """What happened to one camera during a run."""

    frames: int = 0  # frames delivered
    dropped: int = 0  # live frames replaced by a newer one before they were read
    grabbed: int = 0  # frames taken from the source (live: every frame that arrived)
    decoded: int = 0  # frames converted to an image (live: only those a step asked for)
    skipped: int = 0  # recorded frames passed over without decoding (detect_fps, or loop)
    failures: int = 0  # unreadable frames skipped (recorded) or connection losses (live)
    reconnects: int = 0
    down_s: float = 0.0  # time a live camera spent disconnected


def shown_url(url: str) -> str:
    """A URL as messages and summaries may show it: without user and password
    (``***@host``) and without its query (``?***``), which may hold a token."""
    try:
        parts = urlsplit(url)
        host = parts.netloc.rsplit("@", 1)[-1]
    except ValueError:  # malformed: the part after any credentials only
        return "***@" + url.rsplit("@", 1)[-1] if "@" in url else url
    netloc = f"***@{host}" if "@" in parts.netloc else host
    query = "?***" if parts.query else ""
    return f"{parts.scheme}://{netloc}{parts.path}{query}"
