"""The real demo's frames for the detector tests: one step of its 4 cameras."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from stereopose.detection.models import demo_videos


def demo_step(index: int) -> list[np.ndarray]:
    """Frame `index` of each demo camera (BGR), in the cameras' order; skip the test when the
    demo videos are not in the cache."""
    videos = demo_videos()
    if not videos:
        pytest.skip("the demo videos are not in the cache")
    out = []
    for v in videos:
        cap = cv2.VideoCapture(str(v), cv2.CAP_FFMPEG)
        cap.set(cv2.CAP_PROP_POS_FRAMES, index)
        ok, frame = cap.read()
        cap.release()
        assert ok, v
        out.append(frame)
    return out
