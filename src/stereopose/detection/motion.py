"""Motion in one camera, found cheaply on a small grey copy of its frames (as Frigate finds it):
where a newcomer may be, for the regions of detection.regional.

The frame is sampled to about HEIGHT pixels high (every n-th pixel: the frame itself is never
read whole) and blurred; each pixel that differs from a running
average of the past frames by more than `threshold` grey levels is moving; moving pixels are
dilated into blobs, and each blob of at least MIN_AREA small pixels is a box, in pixels of the
frame. A change over most of the frame (the light, the camera's exposure, a camera moved) is no
one's motion: the average starts again from that frame and no box is given.
"""

from __future__ import annotations

import cv2
import numpy as np

HEIGHT = 120  # the small copy's height, pixels
MIN_AREA = 6  # small pixels: a blob smaller than this is noise
ALPHA = 0.1  # how fast the average follows the frames (per frame)
FLOOD = 0.4  # more than this share of the frame moving: a global change, not a person


class MotionDetector:
    """One camera's motion: `update(image)` once per frame, the boxes (N, 4) x1 y1 x2 y2 in the
    image's pixels. The first frame (or the first of another size, or the first after a
    skip) gives none."""

    def __init__(self, threshold: int = 25) -> None:
        if not 1 <= int(threshold) <= 255:
            raise ValueError(f"motion threshold must be 1..255 grey levels, got {threshold}")
        self.threshold = int(threshold)
        self._average: np.ndarray | None = None
        self._shape: tuple[int, ...] | None = None
        self.resets = 0  # global changes seen

    def skip(self) -> None:
        """A frame not looked at (its camera detected whole, motion unused): the average,
        stale after a gap, starts again from the next frame updated (which gives no boxes)."""
        self._average = None

    def update(self, image: np.ndarray) -> np.ndarray:
        step = max(image.shape[0] // HEIGHT, 1)  # every step-th pixel: no pass over the frame
        small = np.ascontiguousarray(image[::step, ::step])
        grey = cv2.GaussianBlur(cv2.cvtColor(small, cv2.COLOR_BGR2GRAY), (5, 5), 0)
        grey = grey.astype(np.float32)
        if self._average is None or self._shape != image.shape:
            self._average, self._shape = grey, image.shape
            return np.zeros((0, 4))
        moving = cv2.absdiff(grey, self._average) > self.threshold
        cv2.accumulateWeighted(grey, self._average, ALPHA)
        if moving.mean() > FLOOD:
            self._average = grey
            self.resets += 1
            return np.zeros((0, 4))
        mask = cv2.dilate(moving.astype(np.uint8), np.ones((3, 3), np.uint8), iterations=2)
        n, _, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
        boxes = [
            (x, y, x + bw, y + bh)
            for x, y, bw, bh, area in stats[1:n]  # label 0 is the still background
            if area >= MIN_AREA
        ]
        if not boxes:
            return np.zeros((0, 4))
        return np.asarray(boxes, dtype=np.float64) * step  # small pixel k is pixel k * step
