"""Regions of a frame worth detecting in: squares around where people are, at the frame's own
resolution; pure geometry, no model and no state.

A region is a square (x, y, side) in pixels of the frame it is cut from, inside the frame where
the frame is large enough (a square larger than a side of the frame keeps to the frame on that
side). Boxes are (N, 4) x1 y1 x2 y2 pixels. The detector sees each region letterboxed into its
region input (detection.regional), so a region smaller than that input is enlarged (a distant
worker seen at the camera's full detail) and a larger one shrunk.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum

import numpy as np

# a person's box grows by this much of its size on each side into its region (MMPose's pose
# trackers take 1.25x the box; a little more here, since the box is a step old or predicted)
MARGIN = 0.2
# a detection within this many pixels of a region's side that is not the frame's was cut by it
EDGE_PX = 4.0


class Why(StrEnum):
    """Why a camera's frame is looked at where it is: the region reasons (and the whole
    frame's), shown to the console joined by "+"."""

    TRACK = "track"  # a tracked person's 3D joints projected
    SEEN = "seen"  # a person detected there at the last step
    MOTION = "motion"  # something moved there
    SCAN = "scan"  # the periodic scan of the whole frame, in tiles or whole
    WHOLE = "whole"  # the whole frame


@dataclass(frozen=True)
class Region:
    """A square of a frame: its top-left corner (x, y) and side, pixels; why it was made
    (Why: track, seen, motion, scan), the reasons merged into it."""

    x: int
    y: int
    side_w: int  # the square's width as cut (the side, or the frame's width if smaller)
    side_h: int
    why: frozenset[Why]

    @property
    def area(self) -> int:
        return self.side_w * self.side_h

    def cut(self, image: np.ndarray) -> np.ndarray:
        """The region's pixels of `image` (a view, not a copy)."""
        return image[self.y : self.y + self.side_h, self.x : self.x + self.side_w]


def _check_boxes(boxes: np.ndarray) -> np.ndarray:
    b = np.asarray(boxes, dtype=np.float64).reshape(-1, 4) if np.size(boxes) else np.zeros((0, 4))
    if b.ndim != 2 or b.shape[1] != 4:
        raise ValueError(f"boxes must have shape (N, 4), got {np.shape(boxes)}")
    return b[np.isfinite(b).all(axis=1) & (b[:, 2] > b[:, 0]) & (b[:, 3] > b[:, 1])]


def place(cx: float, cy: float, side: float, size: tuple[int, int], why: frozenset[Why]) -> Region:
    """The square of `side` centred on (cx, cy), moved inside a frame of `size` (w, h); a side
    larger than the frame's keeps to the frame on that side."""
    w, h = size
    s = max(round(side), 1)
    sw, sh = min(s, w), min(s, h)
    x = round(min(max(cx - sw / 2, 0), w - sw))
    y = round(min(max(cy - sh / 2, 0), h - sh))
    return Region(x, y, sw, sh, why)


def squares(
    boxes: np.ndarray, size: tuple[int, int], why: Why, min_side: float, margin: float = MARGIN
) -> list[Region]:
    """One region per box (N, 4): a square of the box's longer side plus `margin` of it on each
    side, at least `min_side`, centred on the box and moved inside the frame. Boxes wholly
    outside the frame, empty or not finite give none."""
    w, h = size
    out = []
    for x1, y1, x2, y2 in _check_boxes(boxes):
        if x2 <= 0 or y2 <= 0 or x1 >= w or y1 >= h:
            continue
        side = max(max(x2 - x1, y2 - y1) * (1 + 2 * margin), min_side)
        out.append(place((x1 + x2) / 2, (y1 + y2) / 2, side, size, frozenset({why})))
    return out


def merge(
    regions: list[Region],
    size: tuple[int, int],
    largest: float = float("inf"),
    max_growth: float = 1.5,
) -> list[Region]:
    """Regions merged while two of them fit one square not much larger than the larger of the
    two (its side at most `max_growth` times that one's: detail lost by at most that) or overlap
    by half of the smaller: fewer inferences, each person whole in one region. Two regions
    whose merged side would pass `largest` are merged only where they overlap so."""
    out = list(regions)
    merged = True
    while merged and len(out) > 1:
        merged = False
        for i in range(len(out)):
            for j in range(i + 1, len(out)):
                a, b = out[i], out[j]
                x1, y1 = min(a.x, b.x), min(a.y, b.y)
                x2 = max(a.x + a.side_w, b.x + b.side_w)
                y2 = max(a.y + a.side_h, b.y + b.side_h)
                side = max(x2 - x1, y2 - y1)
                larger = max(a.side_w, a.side_h, b.side_w, b.side_h)
                ix = min(a.x + a.side_w, b.x + b.side_w) - max(a.x, b.x)
                iy = min(a.y + a.side_h, b.y + b.side_h) - max(a.y, b.y)
                inter = max(ix, 0) * max(iy, 0)
                near = side <= max_growth * larger and side <= max(largest, larger)
                if near or inter >= 0.5 * min(a.area, b.area):
                    out[i] = place((x1 + x2) / 2, (y1 + y2) / 2, side, size, a.why | b.why)
                    del out[j]
                    merged = True
                    break
            if merged:
                break
    return out


def tiles(size: tuple[int, int], tile: int, overlap: float = 0.25) -> list[Region]:
    """Squares of side `tile` covering a frame of `size` (w, h), neighbours overlapping by
    `overlap` of a tile (a full scan at the frame's own resolution)."""
    w, h = size

    def starts(length: int) -> list[int]:
        if length <= tile:
            return [0]
        n = int(np.ceil((length - tile) / (tile * (1 - overlap)))) + 1
        return [round(k * (length - tile) / (n - 1)) for k in range(n)]

    return [
        Region(x, y, min(tile, w), min(tile, h), frozenset({Why.SCAN}))
        for y in starts(h)
        for x in starts(w)
    ]


def cut_sides(box: np.ndarray, region: Region, size: tuple[int, int]) -> tuple[bool, ...]:
    """Whether a box (4,) in frame pixels touches each side (left, top, right, bottom) of the
    region that is not also the frame's side: the person may go on beyond it."""
    w, h = size
    x1, y1, x2, y2 = box
    r = region
    return (
        r.x > 0 and x1 <= r.x + EDGE_PX,
        r.y > 0 and y1 <= r.y + EDGE_PX,
        r.x + r.side_w < w and x2 >= r.x + r.side_w - EDGE_PX,
        r.y + r.side_h < h and y2 >= r.y + r.side_h - EDGE_PX,
    )


def grow_cut(box: np.ndarray, sides: tuple[bool, ...]) -> np.ndarray:
    """A cut person's box (4,) grown by half its size beyond each side it was cut at: where the
    rest of him is likely to be, for the next step's region."""
    x1, y1, x2, y2 = (float(v) for v in box)
    w, h = x2 - x1, y2 - y1
    ext = 0.5 * max(w, h)
    return np.array(
        [x1 - ext * sides[0], y1 - ext * sides[1], x2 + ext * sides[2], y2 + ext * sides[3]]
    )


def dedupe(
    boxes: np.ndarray,
    scores: np.ndarray,
    cut: np.ndarray,
    iou: float,
    whole: np.ndarray | None = None,
) -> np.ndarray:
    """The detections to keep of one frame found in overlapping regions: whole ones before cut
    ones, then by score. One is dropped when it overlaps a kept one by more than `iou` (box
    IoU: the same person found whole in two regions), or when one of the two was cut by its
    region and it lies mostly (70 %) inside the other (a person cut by one region lies inside
    his whole self from another; two whole people, one behind the other, are both kept), or
    when it was cut and a third of it lies on a whole one (a fragment of him, or a ghost the
    cut made). whole (N,) bool: found in the whole frame, kept before the rest (a scan's
    tiles add only the people the whole frame did not find).
    boxes (N, 4), scores (N,), cut (N,) bool; kept indices."""
    b = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
    cut = np.asarray(cut, dtype=bool)
    first = np.zeros(len(b), bool) if whole is None else np.asarray(whole, dtype=bool)
    order = np.lexsort((-np.asarray(scores, float), cut, ~first))
    area = np.maximum((b[:, 2] - b[:, 0]) * (b[:, 3] - b[:, 1]), 1e-9)
    keep: list[int] = []
    for i in order:
        ok = True
        for k in keep:
            iw = min(b[i, 2], b[k, 2]) - max(b[i, 0], b[k, 0])
            ih = min(b[i, 3], b[k, 3]) - max(b[i, 1], b[k, 1])
            inter = max(iw, 0.0) * max(ih, 0.0)
            if (
                inter / (area[i] + area[k] - inter) > iou
                or ((cut[i] or cut[k]) and inter >= 0.7 * min(area[i], area[k]))
                or (cut[i] and not cut[k] and inter >= 0.3 * area[i])
            ):
                ok = False
                break
        if ok:
            keep.append(int(i))
    return np.asarray(keep, dtype=np.int64)


def in_view(boxes: np.ndarray, size: tuple[int, int], share: float = 0.5) -> np.ndarray:
    """The boxes (N, 4) with at least `share` of their area inside a frame of `size`."""
    b = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
    w, h = size
    iw = np.clip(np.minimum(b[:, 2], w) - np.maximum(b[:, 0], 0), 0, None)
    ih = np.clip(np.minimum(b[:, 3], h) - np.maximum(b[:, 1], 0), 0, None)
    area = (b[:, 2] - b[:, 0]) * (b[:, 3] - b[:, 1])
    with np.errstate(invalid="ignore", divide="ignore"):
        keep = np.isfinite(b).all(axis=1) & (area > 0) & (iw * ih >= share * area)
    return b[keep]


def inside(a: Region, b: Region) -> bool:
    """Whether region a's centre lies in region b."""
    cx, cy = a.x + a.side_w / 2, a.y + a.side_h / 2
    return b.x <= cx <= b.x + b.side_w and b.y <= cy <= b.y + b.side_h


def overlaps_any(box: np.ndarray, others: list[np.ndarray], iou: float = 0.3) -> bool:
    for o in others:
        iw = min(box[2], o[2]) - max(box[0], o[0])
        ih = min(box[3], o[3]) - max(box[1], o[1])
        inter = max(iw, 0.0) * max(ih, 0.0)
        union = (box[2] - box[0]) * (box[3] - box[1]) + (o[2] - o[0]) * (o[3] - o[1]) - inter
        if union > 0 and inter / union > iou:
            return True
    return False
