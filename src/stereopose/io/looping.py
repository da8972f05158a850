"""Recorded cameras played for ever: forward, then backward, then forward again.

A clip played in a plain loop jumps from its last frame to its first, and tracking sees every
person teleport; played back and forth, the motion only reverses. The frame index and its time
(index / fps) keep increasing; only the position in the file swings between 0 and n - 1.
"""

from __future__ import annotations

import logging
from collections.abc import Callable

import cv2
import numpy as np

logger = logging.getLogger(__name__)

# the most bytes of decoded frames a backward pass holds per camera (about ten 1088x1920 frames)
BACKWARD_BUFFER_BYTES = 64 * 2**20


class PingPong:
    """Positions 0, 1, ..., n-1, n-2, ..., 0, 1, ... for an increasing index; n may shrink
    (a file that decodes fewer frames than it announced)."""

    def __init__(self, n: int) -> None:
        if n < 1:
            raise ValueError(f"a loop needs at least one frame, got {n}")
        self.n, self.pos, self.dir = n, 0, 1

    def advance(self) -> None:
        if self.n == 1:
            self.pos = 0
            return
        nxt = self.pos + self.dir
        if not 0 <= nxt < self.n:
            self.dir = -self.dir
            nxt = self.pos + self.dir
        self.pos = min(max(nxt, 0), self.n - 1)

    def shrink(self, n: int) -> None:
        """Only the first n positions exist: turn back at the new end."""
        self.n = max(1, n)
        if self.pos >= self.n:
            self.pos, self.dir = max(self.n - 2, 0), -1


class Seeker:
    """Random access to one video's frames for the backward pass: a chunk of frames ending at
    the asked position is decoded forward once and kept (at most BACKWARD_BUFFER_BYTES), so a
    backward pass costs about one seek per chunk instead of one per frame."""

    def __init__(
        self, cap: cv2.VideoCapture, frame_bytes: int, on_short: Callable[[int], None]
    ) -> None:
        self.cap = cap
        self.size = max(2, BACKWARD_BUFFER_BYTES // max(frame_bytes, 1))
        self.chunk: dict[int, np.ndarray] = {}
        self.cap_pos = 0  # position of the frame the capture reads next
        self.on_short = on_short  # told the number of frames that exist when a read fails

    def frame(self, pos: int) -> np.ndarray | None:
        """The image at `pos`; None if the file does not decode there."""
        if pos in self.chunk:
            return self.chunk[pos]
        if pos == self.cap_pos:  # playing forward: the next frame, nothing kept
            self.chunk.clear()
            return self._read()
        lo = max(0, pos - self.size + 1)
        self._seek(lo)
        self.chunk.clear()
        for p in range(lo, pos + 1):
            image = self._read()
            if image is None:
                return None
            self.chunk[p] = image
        return self.chunk[pos]

    def grab(self, pos: int) -> bool:
        """Pass over the frame at `pos` without converting it (forward only); whether it
        exists. Elsewhere nothing is read: a later frame() seeks."""
        if pos in self.chunk or pos != self.cap_pos:
            return True
        self.chunk.clear()
        if self.cap.grab():
            self.cap_pos += 1
            return True
        self.on_short(self.cap_pos)
        return False

    def _seek(self, pos: int) -> None:
        if self.cap_pos <= pos and pos - self.cap_pos < self.size:
            while self.cap_pos < pos and self.cap.grab():  # near ahead: cheaper than a seek
                self.cap_pos += 1
            return
        self.cap.set(cv2.CAP_PROP_POS_FRAMES, pos)
        self.cap_pos = pos

    def _read(self) -> np.ndarray | None:
        ok, image = self.cap.read()
        if not ok or image is None:
            self.on_short(self.cap_pos)
            return None
        self.cap_pos += 1
        return image
