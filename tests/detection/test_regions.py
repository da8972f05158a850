"""Regions of a frame (pure geometry) and the motion detector that proposes some of them."""

from __future__ import annotations

import numpy as np
import pytest

from stereopose.detection.motion import MotionDetector
from stereopose.detection.regions import (
    Region,
    cut_sides,
    dedupe,
    grow_cut,
    merge,
    place,
    squares,
    tiles,
)

SIZE = (1920, 1080)


def test_a_box_gets_a_square_with_its_margin_inside_the_frame():
    (r,) = squares(np.array([[100, 200, 160, 400]]), SIZE, "seen", min_side=0)
    assert r.side_w == r.side_h == round(200 * 1.4)  # the longer side, 20 % each way
    assert r.why == {"seen"}
    assert r.x == 0  # moved inside, not cut by the frame's side
    (small,) = squares(np.array([[1000, 500, 1010, 520]]), SIZE, "motion", min_side=320)
    assert small.side_w == 320 and small.x == 1005 - 160
    (corner,) = squares(np.array([[1900, 1060, 1920, 1080]]), SIZE, "seen", min_side=320)
    assert (corner.x + corner.side_w, corner.y + corner.side_h) == SIZE


@pytest.mark.parametrize(
    "boxes",
    [
        np.zeros((0, 4)),
        np.array([[np.nan, 0, 10, 10]]),
        np.array([[5, 5, 5, 9]]),
        np.array([[-50, -50, -10, -10]]),
        np.array([[2000, 10, 2100, 90]]),
    ],
)
def test_empty_broken_or_outside_boxes_give_no_region(boxes):
    assert squares(boxes, SIZE, "track", 160) == []


def test_a_square_larger_than_the_frame_keeps_to_it():
    r = place(540, 960, 1500, (1088, 1920), frozenset({"seen"}))
    assert (r.x, r.side_w) == (0, 1088) and r.side_h == 1500
    assert r.cut(np.zeros((1920, 1088, 3))).shape == (1500, 1088, 3)


def test_near_regions_merge_and_far_ones_do_not():
    a = place(500, 500, 300, SIZE, frozenset({"track"}))
    b = place(560, 520, 300, SIZE, frozenset({"motion"}))
    far = place(1500, 500, 300, SIZE, frozenset({"seen"}))
    out = merge([a, b, far], SIZE)
    assert len(out) == 2
    joined = next(r for r in out if "track" in r.why)
    assert joined.why == {"track", "motion"}
    assert joined.side_w >= 360 and joined.x <= a.x and joined.x + joined.side_w >= b.x + b.side_w
    # two people next to each other stay apart where together they would pass `largest`
    assert len(merge([a, place(800, 500, 300, SIZE, frozenset({"seen"}))], SIZE, 400)) == 2


def test_tiles_cover_the_whole_frame_with_overlap():
    ts = tiles(SIZE, 640)
    covered = np.zeros(SIZE[::-1], bool)
    for t in ts:
        covered[t.y : t.y + t.side_h, t.x : t.x + t.side_w] = True
        assert t.side_w == t.side_h == 640 and t.why == {"scan"}
    assert covered.all()
    assert len(ts) == 4 * 2
    assert tiles((320, 200), 640) == [Region(0, 0, 320, 200, frozenset({"scan"}))]


def test_a_box_at_a_regions_inner_side_is_cut_and_at_the_frames_side_is_not():
    r = Region(0, 100, 400, 400, frozenset({"seen"}))
    assert cut_sides(np.array([0, 150, 100, 498]), r, SIZE) == (False, False, False, True)
    assert cut_sides(np.array([300, 101, 399, 300]), r, SIZE) == (False, True, True, False)
    assert cut_sides(np.array([50, 150, 300, 400]), r, SIZE) == (False,) * 4
    grown = grow_cut(np.array([0, 150, 100, 498]), (False, False, False, True))
    assert grown.tolist() == [0, 150, 100, 498 + 174]


def test_dedupe_keeps_one_person_of_overlapping_regions():
    whole = [100, 100, 200, 400]
    again = [101, 99, 201, 402]  # the same person whole in a second region
    cut_part = [100, 100, 200, 250]  # his upper half, cut by a third region's side
    other = [150, 120, 260, 420]  # someone half behind him, whole: kept
    boxes = np.array([cut_part, whole, again, other], float)
    keep = dedupe(
        boxes, np.array([0.95, 0.9, 0.8, 0.85]), np.array([True, False, False, False]), iou=0.7
    )
    assert sorted(keep.tolist()) == [1, 3]
    # a cut person no region holds whole is kept
    assert dedupe(boxes[:1], np.array([0.9]), np.array([True]), 0.7).tolist() == [0]


def test_motion_finds_what_moves_and_ignores_noise_and_a_global_change():
    rng = np.random.default_rng(1)
    grey = np.full((1080, 1920, 3), 100, np.uint8)

    def noisy(im):
        return np.clip(im + rng.normal(0, 2, im.shape), 0, 255).astype(np.uint8)

    m = MotionDetector(threshold=25)
    assert len(m.update(noisy(grey))) == 0  # the first frame: nothing to compare with
    assert len(m.update(noisy(grey))) == 0  # noise is not motion
    moved = grey.copy()
    moved[400:700, 900:1000] = 220  # a bright figure walks in
    boxes = m.update(noisy(moved))
    assert len(boxes) == 1
    x1, y1, x2, y2 = boxes[0]
    assert x1 <= 900 + 20 and x2 >= 1000 - 20 and y1 <= 400 + 20 and y2 >= 700 - 20
    assert x2 - x1 < 300 and y2 - y1 < 450
    assert len(m.update(noisy(np.full_like(grey, 230)))) == 0  # the light changed everywhere
    assert m.resets == 1
    with pytest.raises(ValueError, match=r"1\.\.255"):
        MotionDetector(0)


def test_motion_after_frames_it_skipped_starts_again():
    """A camera detected whole for a while (its motion unused, its frames not read): the
    average, stale, starts again from the next frame, which gives no box (a scene changed in
    the gap is no one's motion); motion after it is found as before."""
    rng = np.random.default_rng(2)
    grey = np.full((1080, 1920, 3), 100, np.uint8)

    def noisy(im):
        return np.clip(im + rng.normal(0, 2, im.shape), 0, 255).astype(np.uint8)

    m = MotionDetector(threshold=25)
    m.update(noisy(grey))
    m.skip()
    changed = grey.copy()
    changed[100:300, 100:400] = 200  # a door opened while the camera was detected whole
    assert len(m.update(noisy(changed))) == 0  # compared with nothing stale
    assert len(m.update(noisy(changed))) == 0
    moved = changed.copy()
    moved[400:700, 900:1000] = 220
    assert len(m.update(noisy(moved))) == 1
    assert m.resets == 0


def test_many_regions_at_once_are_merged_or_give_way_to_the_whole_frame():
    from stereopose.detection.regional import MAX_REGIONS, RegionDetector

    class Nobody:  # no inference needed to plan: the planner alone is looked at
        name, imgsz, iou = "none", 640, 0.7

        def detect(self, images, imgsz=None):
            from stereopose.detection.base import Poses

            return [Poses.empty() for _ in images]

    regions = RegionDetector(Nobody())
    frame = np.full((1080, 1920, 3), 100, np.uint8)
    regions.detect({"c": frame}, 0.0)  # the first scan
    # 40 people spread over the frame, held from the last step: far more than MAX_REGIONS
    xs, ys = np.meshgrid(np.linspace(50, 1800, 8), np.linspace(50, 900, 5))
    regions._state["c"].held = [
        (np.array([x, y, x + 40, y + 100]), 0.05)
        for x, y in zip(xs.ravel(), ys.ravel(), strict=True)
    ]
    regions.detect({"c": frame}, 0.1)
    shown = regions.regions("c")
    assert len(shown) <= MAX_REGIONS
    assert regions.whole("c") or len(shown) >= 1
