"""A live camera's full stream kept as it arrives, encoded: its packets, never decoded.

A camera with a low-resolution detection substream needs its full stream only for the event
clips; decoding it (about 5 ms a 1088x1920 H.264 frame, every frame, since inter-coded video
needs each one) would take a core from the detector for 4 such cameras at 60 fps. So its
reader (io.stream.LiveStream with ``packets``) only demuxes: each packet goes, with its arrival
time and whether it is a keyframe, into a ``PacketRing``, and a clip of the full stream is
those packets written into an MP4 without re-encoding (``StreamCopy``: a stream copy, as camera
recorders do), from the last keyframe at or before the clip's start, then the packets that
arrive after, as the clip goes on (``PacketRing.after``).

The ring holds whole groups of pictures (a keyframe and the packets up to the next one), the
newest ``keep_s`` seconds of them at least, bounded by ``max_bytes``: a group that no longer
fits is dropped whole, oldest first, and counted. Packets before the first keyframe are of no
use to a copy and are passed over.
"""

from __future__ import annotations

import threading
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from stereopose.errors import StereoposeError

__all__ = ["PacketRing", "StreamCopy", "StreamFormat", "write_copy"]

_EPS = 1e-9


@dataclass(frozen=True)
class StreamFormat:
    """What a stream copy needs of the stream: its codec (FourCC text), frame rate and size."""

    fourcc: str
    fps: float
    size: tuple[int, int]


@dataclass
class _Group:
    """A keyframe and the packets after it, up to the next keyframe."""

    packets: list[tuple[float, bytes]] = field(default_factory=list)
    bytes: int = 0

    @property
    def start(self) -> float:
        return self.packets[0][0]


class PacketRing:
    """One camera's newest packets, keyframe-aligned (see the module). Thread-safe: the
    camera's reader pushes, the clip writer reads."""

    def __init__(self, keep_s: float, max_bytes: int) -> None:
        if not keep_s > 0 or not max_bytes > 0:
            raise StereoposeError(
                f"packet ring: keep_s and max_bytes must be > 0, got {keep_s!r}, {max_bytes!r}"
            )
        self.keep_s, self.max_bytes = float(keep_s), int(max_bytes)
        self.format: StreamFormat | None = None
        self.dropped_groups = 0  # whole groups dropped by the byte bound
        self.packets = 0  # packets kept, all told
        self._groups: deque[_Group] = deque()
        self._bytes = 0
        self._lock = threading.Lock()

    @property
    def bytes(self) -> int:
        with self._lock:
            return self._bytes

    def push(self, t: float, keyframe: bool, data: bytes) -> None:
        """One packet that arrived at `t` (seconds on the camera set's clock)."""
        with self._lock:
            if keyframe:
                self._groups.append(_Group())
            elif not self._groups:
                return  # nothing to decode it from
            group = self._groups[-1]
            group.packets.append((float(t), data))
            group.bytes += len(data)
            self._bytes += len(data)
            self.packets += 1
            # the oldest group goes once the next one alone still covers keep_s
            while len(self._groups) > 1 and self._groups[1].start <= t - self.keep_s + _EPS:
                self._bytes -= self._groups.popleft().bytes
            while self._bytes > self.max_bytes and self._groups:
                self._bytes -= self._groups.popleft().bytes
                self.dropped_groups += 1

    def between(self, t0: float, t1: float) -> list[tuple[float, bytes]]:
        """The packets (t, data) that arrived up to `t1`, from the last keyframe at or before
        `t0` (the oldest kept keyframe when that one is gone); [] when none."""
        with self._lock:
            groups = list(self._groups)
        if not groups:
            return []
        first = 0
        for i, g in enumerate(groups):
            if g.start <= t0 + _EPS:
                first = i
        return [(t, data) for g in groups[first:] for t, data in g.packets if t <= t1 + _EPS]

    def after(self, t0: float, t1: float) -> list[tuple[float, bytes]]:
        """The packets (t, data) that arrived after `t0` and up to `t1`: what follows a copy
        written up to `t0`."""
        with self._lock:
            groups = [g for g in self._groups if g.packets[-1][0] > t0 + _EPS]
            return [(t, d) for g in groups for t, d in g.packets if t0 + _EPS < t <= t1 + _EPS]

    def clear(self) -> None:
        """Forget every packet (the stream was reopened: what comes next may differ)."""
        with self._lock:
            self._groups.clear()
            self._bytes = 0


_MP4_TAGS = {
    "h264": "avc1",
    "avc1": "avc1",
    "x264": "avc1",
    "hevc": "hvc1",
    "hev1": "hvc1",
    "hvc1": "hvc1",
    "h265": "hvc1",
}


class StreamCopy:
    """Packets written as they are into the MP4 at `path` (FFmpeg's muxer through OpenCV, no
    re-encoding), in several calls; `close()` then checks that it decodes and returns its
    frame count. StereoposeError if it cannot be written or does not decode (disk full, a
    codec MP4 does not take)."""

    def __init__(self, path: str | Path, fmt: StreamFormat) -> None:
        self.path, self.format = Path(path), fmt
        self.packets = 0
        tag = _MP4_TAGS.get(fmt.fourcc.lower(), fmt.fourcc)
        self._writer: cv2.VideoWriter | None = cv2.VideoWriter(
            str(self.path),
            cv2.CAP_FFMPEG,
            cv2.VideoWriter.fourcc(*tag[:4].ljust(4)),
            fmt.fps,
            fmt.size,
            [cv2.VIDEOWRITER_PROP_RAW_VIDEO, 1],
        )
        if not self._writer.isOpened():
            self._writer = None
            raise StereoposeError(f"{self.path}: cannot write a stream copy of {fmt.fourcc} video")

    def write(self, packets: list[tuple[float, bytes]]) -> None:
        if self._writer is None:
            raise StereoposeError(f"{self.path}: the stream copy is closed")
        for _, data in packets:
            self._writer.write(np.frombuffer(data, np.uint8).reshape(1, -1))
            self.packets += 1

    def release(self) -> None:
        """Close the file without checking it (the copy is being given up)."""
        if self._writer is not None:
            self._writer.release()
            self._writer = None

    def close(self) -> int:
        self.release()
        if not self.packets:
            raise StereoposeError(f"{self.path}: no packets to write")
        cap = cv2.VideoCapture(str(self.path), cv2.CAP_FFMPEG)
        try:
            frames = int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) if cap.isOpened() else 0
            ok = cap.isOpened() and cap.read()[0]
        finally:
            cap.release()
        if not ok or frames <= 0:
            raise StereoposeError(f"{self.path}: the stream copy does not decode (disk full?)")
        return frames


def write_copy(path: str | Path, packets: list[tuple[float, bytes]], fmt: StreamFormat) -> int:
    """The packets (t, data) as one stream copy at `path` (StreamCopy); its frame count."""
    if not packets:
        raise StereoposeError(f"{path}: no packets to write")
    copy = StreamCopy(path, fmt)
    try:
        copy.write(packets)
    finally:
        copy.release()
    return copy.close()
