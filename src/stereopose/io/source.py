"""What every camera source shares: the names of sources, their statistics, their error.

Recorded sources (io.video) and live streams (io.stream) both build on this module.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from stereopose.errors import StereoposeError

STREAM_SCHEMES = ("rtsp://", "rtsps://", "http://", "https://", "rtmp://", "udp://", "tcp://")
IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff", ".webp")


class VideoError(StereoposeError):
    """A camera source is missing, unreadable or corrupt."""


def is_stream(spec: str) -> bool:
    return str(spec).lower().startswith(STREAM_SCHEMES)


def source_name(spec: str) -> str:
    """Default camera name: the file or folder stem; for a URL, its last path part."""
    if is_stream(spec):
        tail = str(spec).rstrip("/").rsplit("/", 1)[-1]
        return tail.split("?")[0].rsplit(".", 1)[0] or "stream"
    return Path(spec).stem


@dataclass
class SourceStats:
    """What happened to one camera during a run."""

    frames: int = 0  # frames delivered
    dropped: int = 0  # live frames replaced by a newer one before they were read
    failures: int = 0  # unreadable frames skipped (recorded) or connection losses (live)
    reconnects: int = 0
    down_s: float = 0.0  # time a live camera spent disconnected
