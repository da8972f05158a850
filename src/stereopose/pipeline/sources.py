"""The frame loop's sources: 2D keypoint files, and cameras with a pose detector."""

from __future__ import annotations

import dataclasses
import logging
import time
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from stereopose.detection import PoseDetector, choice_of
from stereopose.detection.carry import Carrier, carrier
from stereopose.detection.light import LightWatch
from stereopose.detection.openpose import PoseSequence
from stereopose.detection.regional import RegionDetector, region_detector
from stereopose.errors import StereoposeError
from stereopose.io.cameraset import CameraSet
from stereopose.io.summary import CAMERA_STAGES, FILE_STAGES, RunSummary
from stereopose.io.video import FrameSet, usable_images
from stereopose.pipeline.detect import detect_step
from stereopose.pipeline.loop import SourceStep
from stereopose.pipeline.track_regions import held_cameras, track_boxes, watched_shares
from stereopose.secrets import redact_all
from stereopose.types import Camera, People2D, People3D, Rig
from stereopose.zones.hazard import Hazards

if TYPE_CHECKING:
    from stereopose.config import DetectorConfig
    from stereopose.fence import Site

logger = logging.getLogger(__name__)


class KeypointFiles:
    """2D keypoint folders (one per camera) read frame by frame; t = frame / fps.

    A malformed file is skipped (listed in the summary's skipped_files, counted per camera in
    the closing warning) and its frame still goes on with the other cameras.
    """

    stages = FILE_STAGES
    live = False

    def __init__(self, seq: PoseSequence, fps: float) -> None:
        self.seq = seq
        self.cameras = tuple(seq.cameras)
        self.fps = float(fps)
        self.frames_read = 0  # frames with at least one readable file

    @property
    def total(self) -> int:
        return len(self.seq)

    def __iter__(self) -> Iterator[SourceStep]:
        for frame, people2d in self.seq:
            self.frames_read += bool(people2d)
            yield SourceStep(frame, frame / self.fps, people2d)

    def detect(self, step: SourceStep) -> Mapping[str, People2D]:
        raise TypeError("keypoint files carry their 2D people")

    def tracked(self, people: People3D) -> None:
        """Nothing: keypoint files are detected already."""

    def finish(self, summary: RunSummary) -> None:
        summary.frames_read = self.frames_read
        summary.skipped_files = [(str(p), why) for p, why in self.seq.skipped]
        if summary.skipped_files:
            per = ", ".join(f"{cam} {n}" for cam, n in self.seq.skipped_per_camera.items())
            logger.warning(
                "%d keypoint file(s) skipped as unreadable (%s); those cameras have no frame there",
                len(summary.skipped_files),
                per,
            )


def check_size(camera: Camera, image: np.ndarray) -> None:
    """A camera's frames must have its calibration's size."""
    w, h = camera.size
    if (image.shape[1], image.shape[0]) != (round(w), round(h)):
        raise StereoposeError(
            f"camera {camera.name}: frames are {image.shape[1]}x{image.shape[0]} pixels but its "
            f"calibration is for {round(w)}x{round(h)}"
        )


def scale_people(people: People2D, size: tuple[float, float], shape: tuple[int, ...]) -> People2D:
    """People found in a substream frame of `shape` (h, w, ...) in pixels of the camera's own
    (calibrated) `size` (w, h)."""
    sx, sy = size[0] / shape[1], size[1] / shape[0]
    kp = np.array(people.keypoints, dtype=np.float64)
    kp[..., 0] *= sx
    kp[..., 1] *= sy
    boxes = None if people.boxes is None else np.asarray(people.boxes, float) * (sx, sy, sx, sy)
    return People2D(people.camera, people.frame, kp, boxes, people.scores)


class Cameras:
    """Cameras read in step (io.cameraset.CameraSet), their people found by a pose detector.

    Each camera's first frame is checked against its calibration's size. A step's t is the
    set's (recorded: frame / fps, or when its frames were read with the set's wall_clock, as a
    service plays files; live: when its frames arrived, seconds since the cameras were
    opened). A camera with a detection substream is detected on its substream's frame, and its
    people scaled to the calibration's size. `finish` puts each camera's reader statistics
    (frames, dropped, reconnects) into the summary, and for live cameras (or files on the
    wall clock) the wall-clock time of t = 0 (clock_start_epoch).

    regions: detect where the people are (detection.regional), the tracked people of the last
    step the frame loop gave back (`tracked`) projected into each camera; None: whole frames.
    light: each camera's light measured, a night camera's picture prepared for the detector
    (detection.light); None: neither. carry: a camera whose people move slowly skips the
    detector every other step, its people carried on (detection.carry); None: every camera
    detected at every step. hazards: the site's energized zones (zones.hazard); a camera
    that sees a tracked person near one is never carried, nor is any camera while nobody's
    place is known yet (set_hazards: a new site's); None: no site, no hazard.
    """

    stages = CAMERA_STAGES

    def __init__(
        self,
        cams: CameraSet,
        rig: Rig,
        detector: PoseDetector,
        regions: RegionDetector | None = None,
        light: LightWatch | None = None,
        carry: Carrier | None = None,
        hazards: Hazards | None = None,
    ) -> None:
        self.cams, self.rig, self.detector = cams, rig, detector
        self.regions = regions
        self.light = light
        self.carry = carry
        self.hazards = hazards
        self._tracked: People3D | None = None
        self.cameras = tuple(cams.names)
        self.fps = float(cams.fps)
        self.live = bool(cams.live)
        self._checked: set[str] = set()
        self._steps: dict[int, FrameSet] = {}  # the substream frames of the steps given
        self._arrived: dict[int, float] = {}  # monotonic arrival of each step given out

    def set_rig(self, rig: Rig) -> None:
        """The rig from the next step on (a camera placed again while serving)."""
        self.rig = rig

    def set_hazards(self, hazards: Hazards | None) -> None:
        """The hazards from the next step on (a new site while serving)."""
        self.hazards = hazards

    @property
    def total(self) -> int | None:
        return self.cams.count

    def __iter__(self) -> Iterator[SourceStep]:
        for step in self.cams:
            live = self.live and step.times
            arrived = self.cams.clock.start + min(step.times.values()) if live else None
            while len(self._arrived) > 1:
                self._arrived.pop(next(iter(self._arrived)))
            self._arrived[step.index] = arrived if arrived is not None else time.monotonic()
            if step.detect:  # kept for detect(), the one step given out (two, pipelined)
                while len(self._steps) > 1:
                    self._steps.pop(next(iter(self._steps)))
                self._steps[step.index] = step
            yield SourceStep(step.index, step.t, None, step.images)

    def arrival(self, step: SourceStep) -> float:
        """When the step's oldest frame arrived (live) or was read (recorded), monotonic s."""
        return self._arrived.get(step.frame, time.monotonic())

    def detect(self, step: SourceStep) -> Mapping[str, People2D]:
        images = dict(step.images or {})
        full = self._steps.pop(step.frame, None)
        subs = {n: im for n, im in (full.detect if full else {}).items() if im is not None}
        for name, image in usable_images(FrameSet(step.frame, step.t, images)):
            if image is subs.get(name):  # a camera kept encoded shows its substream's frame
                continue
            if name not in self._checked:
                self._checked.add(name)
                check_size(self.rig[name], image)
        frames = FrameSet(step.frame, step.t, {**images, **subs})
        order = [n for n, im in frames.images.items() if im is not None]
        carried = set()
        if self.carry is not None:
            carried = self.carry.plan(
                order, step.frame, step.t, lambda ready: self._held(ready, step.t)
            )
        if carried:
            frames = FrameSet(
                step.frame, step.t, {n: im for n, im in frames.images.items() if n not in carried}
            )
        hints = self._hints(frames, step.t) if self.regions is not None else None
        people2d = detect_step(self.detector, frames, self.regions, hints, self.light)
        for name in people2d.keys() & subs.keys():
            people2d[name] = scale_people(people2d[name], self.rig[name].size, subs[name].shape)
        if self.carry is None:
            return people2d
        for name, people in people2d.items():
            self.carry.seen(name, people, step.frame, step.t)
        for name in carried:
            people2d[name] = self.carry.carried(name, step.frame)
        return {n: people2d[n] for n in order if n in people2d}

    def tracked(self, people: People3D) -> None:
        """The frame loop's people of its last step: the next steps' regions (any thread)."""
        self._tracked = people

    def _held(self, names: list[str], t: float) -> set[str]:
        """The cameras of `names` that must detect at the step at t whatever their people's
        pace: those that see a tracked person near a hazard (zones.hazard) by the time t, a
        hand moving at the hazards' speed from the pose known; every camera while no pose is
        known yet."""
        return held_cameras(self.hazards, self._tracked, self.rig, names, t, self.fps)

    def _hints(self, frames: FrameSet, t: float) -> dict[str, np.ndarray]:
        """Each camera's tracked people's boxes at t, in the pixels of the image detected."""
        people = self._tracked
        if people is None or not len(people):
            return {}
        out = {}
        for name, image in frames.images.items():
            if image is None or name not in self.rig.names:
                continue
            cam = self.rig[name]
            sx, sy = image.shape[1] / cam.size[0], image.shape[0] / cam.size[1]
            out[name] = track_boxes(people, cam, t) * (sx, sy, sx, sy)
        return out

    def finish(self, summary: RunSummary) -> None:
        choice = choice_of(self.detector)
        if choice is not None:
            summary.detector = choice.as_dict()
        if self.light is not None:
            summary.light = self.light.figures()
        if self.carry is not None:
            summary.carry = self.carry.report()
        if self.regions is not None:
            summary.regions = self.regions.report()
        summary.sources = {k: dataclasses.asdict(v) for k, v in self.cams.stats().items()}
        if self.live or self.cams.wall_clock:
            summary.clock_start_epoch = self.cams.clock.start_epoch


def detecting_cameras(
    cams: CameraSet,
    rig: Rig,
    detector: PoseDetector,
    settings: DetectorConfig,
    site: Site | None = None,
) -> Cameras:
    """The cameras detected as `run` and `serve` set them up, from the [detector] settings
    (config.DetectorConfig): in regions (regions and their keys; `site`'s workers watched for
    the scans, None: nobody yet), each camera's light (night), carried steps (carry) never
    near `site`'s energized zones, each taken as live (zones.hazard; serve's set_hazards
    tells which are dead)."""
    regions = region_detector(detector, settings)
    if regions is not None and site is not None:
        regions.watch(watched_shares(rig, site.zones))
    light = LightWatch(enhance=settings.night)
    hazards = Hazards(site.zones) if site is not None else None
    return Cameras(cams, rig, detector, regions, light, carrier(settings), hazards)


def source_label(value: str | Path | Mapping[str, str] | Sequence[str]) -> str:
    """What a run read, for the event log's `runs.source`: camera names, or the sources with
    no URL's password (rtsp://user:***@host/...)."""
    if isinstance(value, (str, Path)):
        return redact_all(str(value))
    return redact_all(", ".join(str(v) for v in value))
