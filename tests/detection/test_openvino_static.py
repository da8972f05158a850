"""OpenVINO models compiled for the shapes a detector meets most: made after AFTER calls of a
shape, at most MOST of them, the same people as the dynamic model, and a shape that cannot
be compiled left to the dynamic model."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from demo_frames import demo_step
from stereopose.detection import make_detector
from stereopose.detection.openvino_static import AFTER, COUNTED, IDLE, MOST, StaticShapes

pytest.importorskip("openvino")


@pytest.mark.realdata
@pytest.mark.slow
def test_a_common_shape_gets_a_model_of_its_own_with_the_same_people():
    frames = demo_step(30)
    det = make_detector("openvino", threads=2, precision="fp32")
    assert det.static is not None and det.static.shapes == []
    first = det.detect(frames)  # 4 portrait frames: split over the two streams, 2 + 2
    for _ in range(AFTER - 2):
        det.detect(frames)
    assert det.static.shapes == []  # not yet: AFTER calls of it
    again = det.detect(frames)
    (way, n, h, w), *_ = det.static.shapes
    assert (way, n) == ("split", 2) and (h, w) == (640, 384)  # letterboxed portrait frames
    assert det.static.calls == 1 and det.static.compile_ms > 0
    for a, b in zip(first, again, strict=True):  # fp32: the very same people and joints
        assert len(a) == len(b) >= 2
        np.testing.assert_allclose(a.keypoints, b.keypoints, atol=1e-3)
        np.testing.assert_allclose(a.boxes, b.boxes, atol=1e-3)
    # one frame at a time is another way and another shape: its own count
    for _ in range(AFTER):
        one = det.detect(frames[:1])
    assert len(det.static.shapes) == 2 and det.static.shapes[1][:2] == ("one", 1)
    np.testing.assert_allclose(one[0].keypoints, first[0].keypoints, atol=1e-3)


def test_at_most_most_shapes_are_compiled_and_the_counts_stay_bounded():
    made: list = []

    def compile_(key):
        made.append(key)
        return [f"request {key}"]

    s = StaticShapes(compile_)
    keys = [("one", 1, 32 * (i + 1), 32) for i in range(MOST + 2)]
    for key in keys:
        for _ in range(AFTER - 1):
            assert s.requests(key) is None
        got = s.requests(key)
        assert (got is not None) is (len(made) <= MOST and made[-1] == key)
    assert made == keys[:MOST] and s.shapes == keys[:MOST]
    assert s.requests(keys[0]) == [f"request {keys[0]}"]  # kept, never compiled again
    assert made == keys[:MOST]
    # a new common shape takes the place of a model only once that one has gone unused for
    # IDLE calls: the models in use stay, whatever else comes
    late = ("split", 2, 64, 64)
    for _ in range(IDLE // 2):
        for key in keys[:MOST]:
            s.requests(key)
        assert s.requests(late) is None
    assert made == keys[:MOST] and s.released == 0
    for _ in range(IDLE):  # the first shape no longer called; the others still are
        for key in keys[1:MOST]:
            s.requests(key)
    assert s.requests(late) == [f"request {late}"]
    assert s.released == 1 and s.shapes == [*keys[1:MOST], late]
    # shapes seen a few times each never pile up counts beyond COUNTED
    t = StaticShapes(compile_)
    for i in range(5 * COUNTED):
        t.requests(("one", 1, i, 1))
    assert len(t._counts) <= COUNTED


def test_a_shape_that_cannot_be_compiled_leaves_the_dynamic_model_alone(caplog):
    def broken(key):
        raise RuntimeError("cannot reshape")

    s = StaticShapes(broken)
    key = ("split", 2, 640, 384)
    with caplog.at_level(logging.WARNING, "stereopose.detection.openvino_static"):
        got = [s.requests(key) for _ in range(AFTER + 3)]
    assert got == [None] * (AFTER + 3) and s.failed
    assert "no model compiled for batches of 2 640x384 over the streams" in caplog.text
    assert caplog.text.count("no model compiled") == 1  # tried once
