"""Detection in regions: each camera's people found where they are, at the camera's own
resolution, instead of in its whole frame shrunk to the model's input.

Per camera and step the regions come from:
- ``track``: boxes given by the caller, each tracked person projected into the camera at the
  step's time (pipeline.regions), so a worker standing still keeps his region for as long as
  he is tracked, and a camera that just missed him looks again where he is;
- ``seen``: the camera's own people of its last steps, each kept for `hold_s` after it was
  last found (someone seen by this camera only; a node, or `detect`, with no 3D at all);
- ``motion``: a cheap motion detector on a small grey copy of the frame (detection.motion),
  for newcomers;
- ``scan``: every `full_scan_s`, staggered across cameras, the whole frame at the detector's
  size, so that someone who walked in unseen and stands still is found within `full_scan_s`
  and one step; where the whole frame sees more coarsely than half the camera's resolution,
  each scan adds one of the frame's overlapping tiles at that resolution in turn (a distant
  worker never seen moving is found within as many scans as there are tiles); a camera's
  first scan takes every tile. Tiles are for workers too small for the whole frame: where the
  site shows that even the farthest worker that matters looks tall enough there (`watch`),
  the scan is the whole frame alone, and a camera of near people costs what its whole frame
  costs.

Regions are squares merged into a few (detection.regions), cut from the frame at its own
resolution and letterboxed each into a `imgsz` x `imgsz` model input: smaller ones are
enlarged (a distant worker at the camera's full detail), larger ones shrunk. Where the whole
frame at the detector's own size would cost less and see every region at least as finely, the
camera is detected whole instead. All regions of all cameras of a step go through the detector
in one batch, the whole frames in another, each split only where the measured prices say two
calls cost less than one (detection.call_costs). Keypoints come back in the frame's pixels; a person
touching a region's side that is not the frame's was cut by it, and is dropped when another
region holds him whole, and otherwise kept, his next region grown toward where the rest of him
must be. A camera with nobody, no motion and no scan due costs no inference at all.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from stereopose.detection.base import Letterbox, PoseDetector, Poses, letterbox_for
from stereopose.detection.call_costs import CallCosts, cheapest
from stereopose.detection.motion import MotionDetector
from stereopose.detection.region_settings import CameraRegions, RegionSettings, describe
from stereopose.detection.regions import (
    Region,
    Why,
    cut_sides,
    dedupe,
    grow_cut,
    in_view,
    inside,
    merge,
    overlaps_any,
    squares,
    tiles,
)

if TYPE_CHECKING:
    from stereopose.config import DetectorConfig

logger = logging.getLogger(__name__)

__all__ = ["CameraRegions", "RegionDetector", "RegionSettings", "describe", "region_detector"]

HELD_MAX = 64  # a camera's own people held for their regions, at most
MAX_REGIONS = 8  # regions of one camera and step; more are merged, or the whole frame taken
# people boxes in regions: they move on between steps, so a little more than motion's
SEEN_MIN_SIDE = 0.5  # of imgsz: a region at most twice enlarged
# a worker at least this tall in the whole frame's model input is found there: a camera whose
# smallest watched worker (watch) is that tall scans its whole frame alone, no tiles
FOUND_WHOLE_PX = 96

# the reasons that say a person is there (a track, a detection at the last step)
_PEOPLE = frozenset({Why.TRACK, Why.SEEN})


@dataclass
class _Camera:
    motion: MotionDetector
    next_scan: float  # the step time of its next full scan
    first_gap: float  # of full_scan_s to its second scan (staggered), then 1
    held: list[tuple[np.ndarray, float]] = field(default_factory=list)  # (box, last found)
    last: list[Region] = field(default_factory=list)  # the regions of its last step
    whole: bool = False  # its last step ran on the whole frame
    size: tuple[int, int] | None = None  # its frames' (w, h)
    scanned: bool = False  # its last step was a full scan
    tile_turn: int = -1  # the tile its last scan looked at


class RegionDetector:
    """A pose detector (detection.PoseDetector) run on regions of each camera's frames.

    `detect(images, t, hints)` once per step: images by camera (BGR uint8, each camera's own
    size), the step's time t (seconds, increasing), hints by camera (N, 4) x1 y1 x2 y2 in that
    camera's image pixels (the tracked people projected); the people found by camera, in the
    images' pixels. `cameras` figures by camera; `regions(camera)` the last step's regions.
    """

    def __init__(
        self,
        detector: PoseDetector,
        settings: RegionSettings | None = None,
        costs: CallCosts | None = None,
    ) -> None:
        self.detector = detector
        # the detector's measured call prices: a camera whose whole frame sees its people well
        # enough goes whole where the step's calls cost less so (None: where its regions take
        # as many model input pixels as the whole frame)
        self.costs = costs
        self.name = detector.name
        self.settings = settings or RegionSettings()
        self.whole_imgsz = int(detector.imgsz)
        self.iou = float(detector.iou)
        self.cameras: dict[str, CameraRegions] = {}
        self._state: dict[str, _Camera] = {}
        self._watched: dict[str, float] = {}

    def watch(self, shares: Mapping[str, float]) -> None:
        """Per camera, how tall the smallest worker looks anywhere he matters, as a share of
        its frame's height (pipeline.track_regions.watched_shares, from the site): so that a
        substream's frames, smaller than the calibration's, are judged at their own size. A
        camera whose frame shows him at least FOUND_WHOLE_PX tall in its whole frame's model
        input scans the whole frame alone: no tile would find anyone it misses. A camera not
        named: tiles as needed. Any thread (a site change)."""
        self._watched = {str(k): float(v) for k, v in shares.items()}

    def regions(self, camera: str) -> list[Region]:
        """The regions of `camera`'s last step (empty: detected whole, or nothing to see);
        any thread."""
        state = self._state.get(camera)
        return list(state.last) if state else []

    def view(self, camera: str) -> dict | None:
        """What `camera`'s last step detected, for the console: {"mode": "regions", "whole",
        "whole+regions" or "idle", "regions": [[x, y, w, h, why], ...]} with x, y, w, h as
        fractions of the frame (so a substream's regions fit the full picture) and why the
        reasons joined by "+"; None before its first step. Any thread."""
        state = self._state.get(camera)
        if state is None or state.size is None:
            return None
        w, h = state.size
        boxes = [
            [
                round(r.x / w, 4),
                round(r.y / h, 4),
                round(r.side_w / w, 4),
                round(r.side_h / h, 4),
                "+".join(sorted(r.why)),
            ]
            for r in list(state.last)
        ]
        mode = (
            ("whole+regions" if boxes else "whole")
            if state.whole
            else ("regions" if boxes else "idle")
        )
        return {"mode": mode, "regions": boxes}

    def whole(self, camera: str) -> bool:
        """Whether `camera`'s last step ran on its whole frame; any thread."""
        state = self._state.get(camera)
        return bool(state and state.whole)

    def report(self) -> dict[str, dict[str, float | int]]:
        """The figures by camera (CameraRegions.as_dict); any thread."""
        return {name: c.as_dict() for name, c in list(self.cameras.items())}

    def _register(self, names: list[str], t: float) -> None:
        """Cameras seen for the first time: each is scanned now, and its next scans staggered
        across the full_scan_s period ((k + 1) / n of it after this one: never longer)."""
        new = [n for n in names if n not in self._state]
        for k, name in enumerate(new):
            self._state[name] = _Camera(
                MotionDetector(self.settings.motion_threshold),
                next_scan=t,
                first_gap=(k + 1) / len(new),
            )
            self.cameras[name] = CameraRegions()

    def _plan(
        self, name: str, image: np.ndarray, t: float, hints: np.ndarray | None, whole: Letterbox
    ) -> tuple[list[Region], bool, bool, bool]:
        """A camera's regions at this step, whether it is a scan, whether it is detected
        whole instead (whole: its frame letterboxed at the detector's imgsz), and whether it
        may go either way, as the step's call prices say (its whole frame sees its people well
        enough: every worker that matters is found whole, or no region sees finer)."""
        s = self.settings
        state = self._state[name]
        h, w = image.shape[:2]
        size = (w, h)
        state.held = [(b, seen) for b, seen in state.held if t - seen <= s.hold_s]
        scan = t >= state.next_scan
        if scan:
            gap = s.full_scan_s * state.first_gap
            state.first_gap = 1.0
            state.next_scan = max(state.next_scan + gap, t + 0.5 * gap)
        whole_scale = min(whole.gain)
        # the largest region seen at least `detail` times as finely as in the whole frame
        largest = s.imgsz / (whole_scale * s.detail)
        small = SEEN_MIN_SIDE * s.imgsz
        people = []
        if hints is not None and len(hints):
            # a track's box mostly outside the view, or too large for a region, is no one this
            # camera sees well: his own detections (seen) or the whole frame's scan say more
            people += [
                r
                for r in squares(in_view(hints, size), size, Why.TRACK, small)
                if max(r.side_w, r.side_h) <= largest
            ]
        if state.held:
            people += squares(np.array([b for b, _ in state.held]), size, Why.SEEN, small)
        found_whole = self._watched.get(name, 0.0) * h * whole_scale >= FOUND_WHOLE_PX
        if (scan and found_whole) or (
            not scan and any(max(r.side_w, r.side_h) > largest for r in people)
        ):
            # detected whole whatever moves (a scan that finds everyone whole, or someone too
            # large for a region): motion's boxes would go unused, and its frame is not read;
            # its average starts again at the next frame it looks at
            state.motion.skip()
            moving = np.zeros((0, 4))
        else:
            moving = state.motion.update(image)
            self.cameras[name].motion_frames += 1
        # motion where nobody is known yet: a newcomer (a known person's moving limbs are in
        # his own region already)
        motion = [
            m
            for m in squares(moving, size, Why.MOTION, s.imgsz)
            if not any(inside(m, r) for r in people)
        ]
        regions = merge(people + motion, size, largest)
        if len(regions) > MAX_REGIONS:  # many at once (a crowd, rain): merged however far apart
            regions = merge(regions, size, largest, max_growth=float("inf"))
        if scan:
            # the whole frame (people of any size whole), and where it sees more coarsely than
            # a tile at half the camera's resolution, the next tile in turn (a scan costs about
            # one whole frame and a region: every tile is looked at once in as many scans);
            # the camera's first scan, every tile
            tile = 2 * s.imgsz
            if found_whole:
                # every worker that matters is found whole: no tile, and a region only for
                # whom the whole frame sees at less than half its detail
                return _finer(regions, s.imgsz, whole_scale), True, True, False
            if whole_scale >= s.imgsz / tile:
                return regions, True, True, False
            grid = tiles(size, tile)
            if state.tile_turn < 0:  # its first scan: it knows nothing yet, every tile
                state.tile_turn = len(grid) - 1
                return [*regions, *grid], True, True, False
            state.tile_turn = (state.tile_turn + 1) % len(grid)
            return [*regions, grid[state.tile_turn]], True, True, False
        if not regions:
            return [], False, False, False
        if len(regions) > MAX_REGIONS:  # still too many: the whole frame costs less
            return [], False, True, False
        if any(max(r.side_w, r.side_h) > largest for r in regions):
            # someone too large for a region's detail: the whole frame, and the regions of
            # people it would see at less than half their region's detail (a distant worker
            # beside a near one)
            return _finer(regions, s.imgsz, whole_scale), False, True, False
        whole_px = whole.input_shape[0] * whole.input_shape[1]
        finest = min(s.imgsz / max(r.side_w, r.side_h) for r in regions)
        if self.costs is not None:
            return regions, False, False, found_whole or whole_scale >= finest
        if len(regions) * s.imgsz**2 >= whole_px and whole_scale >= finest:
            return [], False, True, False  # cheaper whole, and no region seen finer
        return regions, False, False, False

    def detect(
        self,
        images: Mapping[str, np.ndarray],
        t: float,
        hints: Mapping[str, np.ndarray] | None = None,
    ) -> dict[str, Poses]:
        s = self.settings
        crops: list[np.ndarray] = []
        owners: list[tuple[str, Region]] = []
        wholes: list[str] = []
        self._register(list(images), t)
        plans = {}
        for name, image in images.items():
            lb = letterbox_for(image.shape[:2], self.whole_imgsz, 32, auto=True)
            plans[name] = (lb, *self._plan(name, image, t, (hints or {}).get(name), lb))
        turned = self._cheapest(plans)
        for name, image in images.items():
            h, w = image.shape[:2]
            lb, regions, scan, whole, _ = plans[name]
            if name in turned:
                regions, whole = [], True
            stats = self.cameras[name]
            stats.steps += 1
            stats.frame_px += w * h
            stats.whole_input_px += lb.input_shape[0] * lb.input_shape[1]
            stats.full_scans += scan
            if whole:
                wholes.append(name)
                stats.whole_frames += 1
                stats.input_px += lb.input_shape[0] * lb.input_shape[1]
                stats.crop_px += w * h
            elif not regions:
                stats.idle_steps += 1
            stats.regions += len(regions)
            stats.input_px += len(regions) * s.imgsz**2
            stats.crop_px += sum(r.area for r in regions)
            self._state[name].last = regions
            self._state[name].whole = whole
            self._state[name].size = (w, h)
            self._state[name].scanned = scan
            for r in regions:
                crops.append(r.cut(image))
                owners.append((name, r))
        found: dict[str, list[tuple[Poses, Region | None]]] = {n: [] for n in images}
        if crops:
            got = self._call(crops, (s.imgsz, s.imgsz), s.imgsz)
            for (name, r), poses in zip(owners, got, strict=True):
                found[name].append((poses, r))
        if wholes:
            shapes = {plans[n][0].input_shape for n in wholes}
            got = self._call(
                [images[n] for n in wholes], shapes.pop() if len(shapes) == 1 else None
            )
            for name, poses in zip(wholes, got, strict=True):
                found[name].append((poses, None))
        out: dict[str, Poses] = {}
        for name, image in images.items():
            h, w = image.shape[:2]
            out[name] = self._gather(name, found[name], (w, h), t)
        return out

    def _cheapest(self, plans: Mapping[str, tuple]) -> set[str]:
        """The cameras that may go either way and are detected whole at this step, for the
        least time by the detector's call prices: only at a step that detects some camera
        whole anyway (a scan, people too large), where joining that batch may spare the call
        of crops; a step of regions alone is one call already (none without prices)."""
        if self.costs is None or not any(p[3] for p in plans.values()):
            return set()
        either = [(n, p[0].input_shape, len(p[1])) for n, p in plans.items() if p[4]]
        if not either:
            return set()
        imgsz = self.settings.imgsz
        needs: dict[tuple[int, int], int] = {(imgsz, imgsz): 2 * len(plans)}
        for lb, *_ in plans.values():
            needs[lb.input_shape] = needs.get(lb.input_shape, 0) + 1
        self.costs.ensure(needs)
        whole = [p[0].input_shape for p in plans.values() if p[3]]
        return cheapest(self.costs, whole, (imgsz, imgsz), either)

    def _call(
        self, images: list[np.ndarray], shape: tuple[int, int] | None, imgsz: int | None = None
    ) -> list[Poses]:
        """The detector's calls for images of one input shape (`shape`; None: several), as
        many as their prices say cost least, each one's time told to the prices."""
        sizes = [len(images)]
        if self.costs is not None and shape is not None:
            sizes = self.costs.split(shape, len(images))
        got: list[Poses] = []
        for n in sizes:
            part, images = images[:n], images[n:]
            t0 = time.perf_counter()
            got += self.detector.detect(part, imgsz=imgsz) if imgsz else self.detector.detect(part)
            if self.costs is not None and shape is not None:
                self.costs.observe(shape, n, 1000 * (time.perf_counter() - t0))
        return got

    def _gather(
        self, name: str, found: list[tuple[Poses, Region | None]], size: tuple[int, int], t: float
    ) -> Poses:
        """One camera's people from its regions, in frame pixels, each person once; its held
        people and newcomer counts brought up to date."""
        kps, boxes, scores, cut, grown, why = [], [], [], [], [], []
        whole_why = frozenset({Why.WHOLE, Why.SCAN} if self._state[name].scanned else {Why.WHOLE})
        for poses, r in found:
            if not len(poses):
                continue
            kp, bx = np.array(poses.keypoints, float), np.array(poses.boxes, float)
            if r is not None:
                kp[..., 0] += r.x
                kp[..., 1] += r.y
                bx[:, [0, 2]] += r.x
                bx[:, [1, 3]] += r.y
            for k in range(len(poses)):
                sides = cut_sides(bx[k], r, size) if r is not None else (False,) * 4
                kps.append(kp[k])
                boxes.append(bx[k])
                scores.append(float(poses.scores[k]))
                cut.append(any(sides))
                grown.append(grow_cut(bx[k], sides) if any(sides) else bx[k])
                why.append(r.why if r is not None else whole_why)
        stats, state = self.cameras[name], self._state[name]
        if not kps:
            return Poses.empty()
        whole = np.array([Why.WHOLE in w for w in why])
        keep = dedupe(np.array(boxes), np.array(scores), np.array(cut), self.iou, whole)
        known = [b for b, _ in state.held]
        for i in keep:
            cx, cy = (boxes[i][0] + boxes[i][2]) / 2, (boxes[i][1] + boxes[i][3]) / 2
            if (
                Why.TRACK in why[i]
                or Why.SEEN in why[i]
                or any(b[0] <= cx <= b[2] and b[1] <= cy <= b[3] for b in known)
            ):
                continue
            if Why.MOTION in why[i]:
                stats.found_by_motion += 1
            elif Why.SCAN in why[i]:
                stats.found_by_scan += 1
        new = [grown[i] for i in keep]
        state.held = [(b, seen) for b, seen in state.held if not overlaps_any(b, new)]
        state.held = ([(b, t) for b in new] + state.held)[:HELD_MAX]
        stats.people += len(keep)
        return Poses(
            np.array([kps[i] for i in keep]),
            np.array([boxes[i] for i in keep]),
            np.array([scores[i] for i in keep]),
        )


def _finer(regions: list[Region], imgsz: int, whole_scale: float) -> list[Region]:
    """The regions of people the whole frame (at whole_scale) sees at less than half the
    detail of their region (at imgsz): kept beside the whole frame."""
    return [
        r for r in regions if imgsz / max(r.side_w, r.side_h) > 2 * whole_scale and r.why & _PEOPLE
    ]


def region_detector(detector: PoseDetector, settings: DetectorConfig) -> RegionDetector | None:
    """The RegionDetector of a detector and its `[detector]` settings (config.DetectorConfig:
    regions, region_imgsz, full_scan_s, motion_threshold), the detector's calls priced on
    this machine (detection.call_costs); None with regions = false."""
    if not settings.regions:
        return None
    return RegionDetector(
        detector,
        RegionSettings(
            imgsz=settings.region_imgsz,
            full_scan_s=settings.full_scan_s,
            motion_threshold=settings.motion_threshold,
            detail=settings.region_detail,
        ),
        CallCosts.of(detector),
    )
