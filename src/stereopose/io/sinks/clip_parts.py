"""The clips' parts: which events are alarms worth a clip, the clip settings, a clip's file
name, the per-camera frame ring and one clip being written (io.sinks.clips uses them)."""

from __future__ import annotations

import logging
import math
import re
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path

import cv2
import numpy as np

from stereopose.alarms.levels import TICKET_ALARMS
from stereopose.behaviour.definitions import ALARM_TYPES, BEHAVIOUR_KIND
from stereopose.io.mp4 import FrameWriter
from stereopose.io.packets import StreamCopy
from stereopose.io.settings import check_settings, ranged
from stereopose.types import Event, People2D, People3D

__all__ = [
    "CLIP_SUFFIX",
    "FULL_SUFFIX",
    "PART_SUFFIX",
    "ClipSettings",
    "Draw",
    "clip_name",
    "is_alarm",
]

logger = logging.getLogger(__name__)

CLIP_SUFFIX = ".mp4"
FULL_SUFFIX = ".full.mp4"  # a clip's full-stream copy, beside it
PART_SUFFIX = ".part.mp4"  # a clip being written
EPS = 1e-9  # frame times compared with some slack
MAX_TWINS = 999

# (camera, image (H, W, 3) BGR, its 2D people or None, the 3D people, scale, label) -> the
# picture to keep, about `scale` times the image's size
Draw = Callable[[str, np.ndarray, "People2D | None", People3D, float, str], np.ndarray]


TICKET_KIND = "ticket"  # tickets.monitor's
TICKET_CLIPPED = TICKET_ALARMS | {"step_done"}


def is_alarm(e: Event) -> bool:
    """The default alarm: entering or approaching an energized zone, a behaviour alarm
    (person_down, lone_worker, work_position, immobile, overreach), or a ticket's step done or
    deviation by a person (the clips of each step and deviation)."""
    if e.kind == BEHAVIOUR_KIND:
        return e.type in ALARM_TYPES
    if e.kind == TICKET_KIND:
        return e.type in TICKET_CLIPPED and e.person >= 0
    return e.kind == "energized" and e.type in ("enter", "approach")


def plain_picture(image: np.ndarray, scale: float) -> np.ndarray:
    h, w = image.shape[:2]
    return (
        image
        if scale == 1.0
        else cv2.resize(image, (max(1, round(w * scale)), max(1, round(h * scale))))
    )


@dataclass(frozen=True, kw_only=True)
class ClipSettings:
    """Keys of the `[storage]` section. clip_pre_s, clip_post_s: seconds before and after an
    alarm; clip_max_s: the longest clip (alarms that keep coming start a new one);
    clip_buffer_frames, clip_buffer_bytes: the most each camera's buffer holds;
    clip_queue_frames: frames waiting for the buffer thread; clip_jpeg_quality; clip_scale:
    the clips' size relative to the camera images; clip_close_timeout_s: how long `close`
    waits for the clips under way."""

    clip_pre_s: float = ranged(5.0, ge=0.0, le=60.0)
    clip_post_s: float = ranged(10.0, ge=0.0, le=600.0)
    clip_max_s: float = ranged(120.0, gt=0.0, le=3600.0)
    clip_buffer_frames: int = ranged(600, ge=1, le=100_000, integer=True)
    clip_buffer_bytes: int = ranged(64 * 2**20, ge=2**16, le=2**36, integer=True)
    clip_queue_frames: int = ranged(64, ge=1, le=10_000, integer=True)
    clip_jpeg_quality: int = ranged(85, ge=10, le=100, integer=True)
    clip_scale: float = ranged(0.5, gt=0.0, le=1.0)
    clip_close_timeout_s: float = ranged(10.0, ge=0.0, le=600.0)

    def __post_init__(self) -> None:
        check_settings(self, "storage")


_UNSAFE = re.compile(r"[^A-Za-z0-9_.-]+")


def part_name(text: str, limit: int = 48) -> str:
    """One part of a file name from any text: letters, digits, '_', '.', '-' kept (the rest
    as '-'), no leading dot, at most `limit` characters, never empty."""
    safe = _UNSAFE.sub("-", text).lstrip(".-")[:limit].rstrip(".-")
    return safe or "x"


def clip_name(wall_t: float, person: int, zone: str, camera: str) -> str:
    """`<UTC time>_<person>_<zone>_<camera>` (no suffix), every part safe in a file name."""
    stamp = datetime.fromtimestamp(wall_t, UTC).strftime("%Y%m%d-%H%M%S")
    return f"{stamp}_{part_name(str(person))}_{part_name(zone)}_{part_name(camera)}"


class FrameRing:
    """One camera's last frames as (t, JPEG bytes), bounded by age, count and bytes."""

    def __init__(self, keep_s: float, max_frames: int, max_bytes: int) -> None:
        self.keep_s, self.max_frames, self.max_bytes = keep_s, max_frames, max_bytes
        self.frames: deque[tuple[float, bytes]] = deque()
        self.bytes = 0
        self.dropped = 0  # by the count or byte bound, not by age

    def push(self, t: float, jpeg: bytes) -> None:
        self.frames.append((t, jpeg))
        self.bytes += len(jpeg)
        while self.frames and self.frames[0][0] < t - self.keep_s - EPS:
            self._pop()
        while len(self.frames) > self.max_frames or self.bytes > self.max_bytes:
            self._pop()
            self.dropped += 1

    def _pop(self) -> None:
        self.bytes -= len(self.frames.popleft()[1])

    def since(self, t0: float) -> list[tuple[float, bytes]]:
        return [f for f in self.frames if f[0] >= t0 - EPS]


@dataclass(eq=False)
class OpenClip:
    camera: str
    name: str
    start_t: float
    end_t: float
    limit_t: float
    last_t: float = -math.inf
    frames: int = 0
    part: Path | None = None
    writer: FrameWriter | None = None
    copy: StreamCopy | None = None  # the full stream's copy under way
    copy_t: float = -math.inf  # the time of its last packet written
    copy_failed: bool = False
    failed: bool = False
    events: list[Event] = field(default_factory=list)
