"""Letterboxing, NMS and decoding of the pose head, without a model."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from stereopose.detection.base import (
    Poses,
    check_image,
    decode,
    group_by_shape,
    letterbox_for,
    letterbox_image,
    nms,
    to_blob,
)


def test_portrait_frame_letterboxed_to_its_aspect_ratio():
    lb = letterbox_for((1920, 1088), 640)
    assert lb.input_shape == (640, 384)  # half the pixels of 640x640
    assert lb.resized == (363, 640)
    assert (lb.left, lb.right, lb.top, lb.bottom) == (10, 11, 0, 0)


def test_fixed_input_pads_to_the_full_square():
    lb = letterbox_for((1920, 1088), (640, 640), auto=False)
    assert lb.input_shape == (640, 640)
    assert (lb.left, lb.right) == (138, 139)


@settings(max_examples=200, deadline=None)
@given(st.integers(20, 4000), st.integers(20, 4000), st.sampled_from([320, 480, 640, 960]))
def test_letterbox_input_is_a_stride_multiple_holding_the_image(h, w, imgsz):
    lb = letterbox_for((h, w), imgsz)
    ih, iw = lb.input_shape
    assert ih % 32 == 0 and iw % 32 == 0 and max(ih, iw) == imgsz
    assert lb.resized[0] + lb.left + lb.right == iw
    assert lb.resized[1] + lb.top + lb.bottom == ih
    assert abs(lb.left - lb.right) <= 1 and abs(lb.top - lb.bottom) <= 1


def test_letterbox_image_pads_grey():
    img = np.zeros((100, 40, 3), np.uint8)
    lb = letterbox_for(img.shape[:2], 64)
    assert lb.left == 3
    out = letterbox_image(img, lb)
    assert out.shape == (*lb.input_shape, 3)
    assert (out[:, : lb.left] == 114).all() and (
        out[:, lb.left : lb.left + lb.resized[0]] == 0
    ).all()
    blob = to_blob([out, out])
    assert blob.shape == (2, 3, *lb.input_shape) and blob.dtype == np.float32
    assert blob.max() == pytest.approx(114 / 255)


def _iou(a, b):
    w = max(0.0, min(a[2], b[2]) - max(a[0], b[0]))
    h = max(0.0, min(a[3], b[3]) - max(a[1], b[1]))
    inter = w * h
    return inter / ((a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - inter)


@st.composite
def box_sets(draw):
    """Boxes (n, 4) x1 y1 x2 y2 in a 280 px square, and distinct scores (n,)."""
    n = draw(st.integers(1, 40))
    xy = draw(arrays(np.float64, (n, 2), elements=st.floats(0.0, 200.0)))
    wh = draw(arrays(np.float64, (n, 2), elements=st.floats(10.0, 80.0)))
    order = np.array(draw(st.permutations(range(n))))
    return np.hstack([xy, xy + wh]), order / n + 0.01


@settings(max_examples=100, deadline=None)
@given(box_sets())
def test_nms_keeps_the_best_of_each_overlapping_cluster(case):
    boxes, scores = case
    keep = nms(boxes, scores, 0.5)
    # reference: greedy over the score order
    ref = []
    for i in np.argsort(-scores):
        if all(_iou(boxes[i], boxes[j]) <= 0.5 for j in ref):
            ref.append(i)
    assert list(keep) == ref


def _head(points_in, boxes_in, scores, n_anchors=50):
    """A raw (56, N) head output holding these people among low-score anchors."""
    out = np.zeros((56, n_anchors), np.float32)
    out[4] = 0.01
    for k, (pts, box, s) in enumerate(zip(points_in, boxes_in, scores, strict=True)):
        x1, y1, x2, y2 = box
        out[:4, k * 3] = ((x1 + x2) / 2, (y1 + y2) / 2, x2 - x1, y2 - y1)
        out[4, k * 3] = s
        out[5:, k * 3] = pts.ravel()
    return out


def test_decode_maps_input_pixels_back_to_the_original_image():
    lb = letterbox_for((1920, 1088), 640)
    gx, gy = lb.gain
    rng = np.random.default_rng(3)
    orig = np.dstack([rng.uniform(100, 1000, (2, 17)), rng.uniform(100, 1800, (2, 17))])
    vis = rng.uniform(0.1, 1, (2, 17, 1))
    inp = np.concatenate([orig * (gx, gy) + (lb.left, lb.top), vis], axis=2)
    boxes_orig = np.array([[100, 100, 500, 1700], [600, 200, 1000, 1800.0]])
    boxes_in = boxes_orig * (gx, gy, gx, gy) + (lb.left, lb.top, lb.left, lb.top)
    poses = decode(_head(inp, boxes_in, [0.6, 0.9]), lb, conf=0.25, iou=0.7, max_det=300)
    assert len(poses) == 2
    order = [1, 0]  # by decreasing score
    np.testing.assert_allclose(poses.keypoints[..., :2], orig[order], atol=1e-3)
    np.testing.assert_allclose(poses.keypoints[..., 2:], vis[order], atol=1e-6)
    np.testing.assert_allclose(poses.boxes, boxes_orig[order], atol=1e-3)
    np.testing.assert_allclose(poses.scores, [0.9, 0.6], atol=1e-6)
    people = poses.people("cam01", 7)
    assert people.frame == 7 and len(people) == 2


def test_decode_clips_to_the_image_and_handles_nobody():
    lb = letterbox_for((100, 100), 64)
    pts = np.full((1, 17, 3), 0.9)
    pts[0, :, :2] = -5.0  # in the padding, left of the image
    poses = decode(_head(pts, [[-10, -10, 30, 30]], [0.8]), lb, 0.25, 0.7, 300)
    assert (poses.keypoints[..., :2] == 0).all() and (poses.boxes[0, :2] == 0).all()
    nobody = decode(np.zeros((56, 10), np.float32), lb, 0.25, 0.7, 300)
    assert len(nobody) == 0 and nobody.keypoints.shape == (0, 17, 3)
    with pytest.raises(ValueError, match="56"):
        decode(np.zeros((55, 10)), lb, 0.25, 0.7, 300)


def test_check_image_rejects_what_is_not_a_bgr_image():
    assert check_image(np.zeros((4, 5), np.uint8), 0).shape == (4, 5, 3)
    with pytest.raises(ValueError, match="image 2"):
        check_image(np.zeros((0, 5, 3), np.uint8), 2)
    with pytest.raises(ValueError, match="uint8"):
        check_image(np.zeros((4, 5, 3), np.float32), 0)
    with pytest.raises(ValueError, match="shape"):
        check_image(np.zeros((4, 5, 4), np.uint8), 0)


def test_images_grouped_by_size():
    a, b = np.zeros((10, 20, 3), np.uint8), np.zeros((20, 10, 3), np.uint8)
    assert group_by_shape([a, b, a]) == {(10, 20): [0, 2], (20, 10): [1]}
    assert len(Poses.empty()) == 0
