"""Detection runs: camera sources -> pose detector -> 2D keypoint files (OpenPose layout)."""

from __future__ import annotations

import glob
import logging
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from stereopose.detection import PoseDetector
from stereopose.detection.light import LightWatch
from stereopose.detection.openpose import write_pose_frame
from stereopose.detection.regional import RegionDetector
from stereopose.errors import KeypointsError
from stereopose.io.cameraset import CameraSet
from stereopose.io.video import (
    FrameSet,
    SourceStats,
    is_stream,
    source_name,
    usable_images,
)
from stereopose.io.writing import probe_folder
from stereopose.pipeline.interrupt import Interrupt
from stereopose.pipeline.paths import (
    Place,
    check_places,
    pattern_products,
    places,
    previous_outputs,
    remove_outputs,
)
from stereopose.types import People2D

logger = logging.getLogger(__name__)

# recorded cameras' next steps decoded while the detector runs on this one (io.cameraset's
# read_ahead; bounded: a step of 4 full-HD cameras is about 25 MB)
READ_AHEAD = 2


@dataclass
class DetectionSummary:
    """What a detection run did: per camera frames and people, and where the time went."""

    backend: str
    cameras: tuple[str, ...]
    steps: int = 0
    frames: dict[str, int] = field(default_factory=dict)  # camera -> frames detected
    people: dict[str, int] = field(default_factory=dict)  # camera -> people found, all frames
    frames_with_people: dict[str, int] = field(default_factory=dict)
    seconds_decode: float = 0.0
    seconds_detect: float = 0.0
    seconds_write: float = 0.0
    sources: dict[str, SourceStats] = field(default_factory=dict)
    interrupted: bool = False
    # camera -> why its keypoint files stopped being written (a full or vanished disk): that
    # camera's files are complete up to the failure, the other cameras go on
    failed_outputs: dict[str, str] = field(default_factory=dict)
    # camera -> detection in regions' figures (detection.regional.CameraRegions); empty: whole
    # frames
    regions: dict[str, dict[str, float | int]] = field(default_factory=dict)

    @property
    def images(self) -> int:
        return sum(self.frames.values())

    @property
    def ms_per_image(self) -> float:
        return 1000 * self.seconds_detect / self.images if self.images else float("nan")


def detect_step(
    detector: PoseDetector,
    step: FrameSet,
    regions: RegionDetector | None = None,
    hints: Mapping[str, np.ndarray] | None = None,
    light: LightWatch | None = None,
) -> dict[str, People2D]:
    """The people of each camera with a usable image at this step: in one detector call over
    the whole frames, or with `regions` in the regions where people are (detection.regional;
    hints: each camera's tracked people's boxes (N, 4) in its image's pixels); light: each
    camera's light measured, and a night camera's picture prepared for the detector."""
    present = usable_images(step)
    if light is not None and present:
        seen = light.prepare(dict(present), step.t)
        present = [(n, seen[n]) for n, _ in present]
    if regions is not None:
        found = regions.detect(dict(present), step.t, hints) if present else {}
        return {n: found[n].people(n, step.index) for n, _ in present}
    found_all = detector.detect([im for _, im in present]) if present else []
    return {n: f.people(n, step.index) for (n, _), f in zip(present, found_all, strict=True)}


def _detect_frames(
    cams: CameraSet,
    detector: PoseDetector,
    out_dir: Path,
    summary: DetectionSummary,
    interrupt: Interrupt,
    on_step: Callable[[int, int | None, float], None] | None,
    regions: RegionDetector | None = None,
) -> None:
    """Each step of `cams` detected and written, until their end or a stop (Ctrl-C)."""
    total = cams.count
    start = time.perf_counter()
    it = iter(cams)
    while not interrupt.stop.is_set():
        t0 = time.perf_counter()
        with interrupt.wait():
            step = next(it, None)
        t1 = time.perf_counter()
        summary.seconds_decode += t1 - t0
        if step is None:
            break
        people2d = detect_step(detector, step, regions)
        t2 = time.perf_counter()
        for name, people in people2d.items():
            if name in summary.failed_outputs:
                continue
            try:
                write_pose_frame(out_dir, name, people)
            except KeypointsError as e:  # the disk, not the input: log once, go on
                summary.failed_outputs[name] = str(e).removeprefix(f"{out_dir / name}_json: ")
                logger.error("camera %s: keypoint files no longer written: %s", name, e)
                continue
            summary.frames[name] += 1
            summary.people[name] += len(people)
            summary.frames_with_people[name] += bool(len(people))
        summary.seconds_detect += t2 - t1
        summary.seconds_write += time.perf_counter() - t2
        summary.steps += 1
        if on_step is not None:
            elapsed = time.perf_counter() - start
            on_step(summary.steps, total, summary.steps / elapsed if elapsed else 0.0)


def _places(
    sources: Sequence[str | Path],
    out_dir: Path,
    names: Sequence[str] | None,
    model: str | Path | None,
) -> tuple[list[Place], list[Place]]:
    """The paths a detection run reads (its recorded sources, the model) and writes (the
    folder and each camera's keypoints folder in it)."""
    specs = [str(s) for s in sources]
    cameras = list(names) if names is not None else [source_name(s) for s in specs]
    inputs = [Place("--videos", Path(s)) for s in specs if not is_stream(s)]
    inputs += places(("--model", model))
    outputs = [Place("--out", out_dir, folder=True)]
    outputs += [Place(f"--out's {n}_json", out_dir / f"{n}_json", folder=True) for n in cameras]
    return inputs, outputs


def detect_videos(
    sources: Sequence[str | Path],
    out_dir: str | Path,
    detector: PoseDetector,
    names: Sequence[str] | None = None,
    sync: str = "index",
    fps: float | None = None,
    max_frames: int | None = None,
    on_step: Callable[[int, int | None, float], None] | None = None,
    overwrite: bool = False,
    model: str | Path | None = None,
    open_timeout_s: float = 5.0,
    first_frame_timeout_s: float | None = 30.0,
    regions: RegionDetector | None = None,
) -> DetectionSummary:
    """Detect people in every camera's frames and write ``<out_dir>/<camera>_json/`` files.

    Frame numbers are the step indices shared by all cameras (aligned by index or time, see
    ``CameraSet``); a camera with no image at a step gets no file there. ``on_step(done, total,
    fps)`` is called after each step. Ctrl-C stops the run after the step in progress (at once
    while waiting for a live camera; pipeline.interrupt): the files written so far are complete.
    open_timeout_s, first_frame_timeout_s: live cameras' bounds (io.cameraset.CameraSet).
    regions: detect in the regions where people are (detection.regional: each camera's own
    people, motion, full scans), around `detector`; None: whole frames.

    No output may be an input (a source, `model`) or lie inside an input folder; keypoint
    files of a previous run in these cameras' folders are refused unless `overwrite`, which
    removes them once the cameras are open (other cameras' folders are left as they are).
    """
    out_dir = Path(out_dir)
    inputs, outputs = _places(sources, out_dir, names, model)
    check_places(inputs, outputs)
    folder = Place("--out", out_dir)
    # each camera's keypoints folder holds one run; other cameras' folders are not this run's
    own = [f"{glob.escape(p.path.name)}/*.json" for p in outputs[1:]]
    previous = previous_outputs(folder, pattern_products(own), overwrite, inputs)
    with CameraSet(
        sources,
        names,
        sync=sync,
        fps=fps,
        max_frames=max_frames,
        open_timeout_s=open_timeout_s,
        first_frame_timeout_s=first_frame_timeout_s,
        read_ahead=READ_AHEAD,
    ) as cams:
        remove_outputs(previous)
        probe_folder(out_dir, "keypoint files")  # before any frame: exit 2, nothing detected
        summary = DetectionSummary(detector.name, tuple(cams.names))
        for name in cams.names:
            summary.frames[name] = summary.people[name] = summary.frames_with_people[name] = 0
        interrupt = Interrupt(threading.Event())
        try:
            with interrupt.installed():
                _detect_frames(cams, detector, out_dir, summary, interrupt, on_step, regions)
        except KeyboardInterrupt:
            interrupt.stop.set()
        if interrupt.stop.is_set():
            summary.interrupted = True
            logger.warning(
                "interrupted after %d frames; files written so far are complete", summary.steps
            )
        summary.sources = cams.stats()
        if regions is not None:
            summary.regions = regions.report()
    for name, n in summary.frames.items():
        if n == 0:
            logger.warning("camera %s: no frame detected", name)
    return summary
