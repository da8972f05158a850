"""Wires the stages together; the only module that knows them all."""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from stereopose.calibration.formats import load_calibration
from stereopose.config import Config
from stereopose.detection.openpose import read_pose_dir
from stereopose.errors import CalibrationError, KeypointsError
from stereopose.io.results import PosesWriter, load_people3d
from stereopose.reconstruction import Reconstructor
from stereopose.sim import Metrics, Scene, evaluate
from stereopose.types import People3D

logger = logging.getLogger(__name__)


@dataclass
class ReconstructionSummary:
    """What a reconstruction run did, for the terminal and for benchmarks."""

    mode: str
    cameras: tuple[str, ...]
    frames: int = 0
    people_histogram: dict[int, int] = field(default_factory=dict)  # people per frame -> frames
    joints_reconstructed: int = 0
    reprojection_px: list[float] = field(default_factory=list, repr=False)
    confident_reprojection_px: list[float] = field(default_factory=list, repr=False)
    skipped_files: list[tuple[str, str]] = field(default_factory=list)
    seconds_3d: float = 0.0
    frames_read: int = 0  # frames with at least one readable keypoint file

    def add(self, people: People3D) -> None:
        self.frames += 1
        n = len(people)
        self.people_histogram[n] = self.people_histogram.get(n, 0) + 1
        ok = np.isfinite(people.reprojection_px)
        self.joints_reconstructed += int(ok.sum())
        self.reprojection_px.extend(people.reprojection_px[ok].tolist())
        conf = ok & (people.conf > 0.5)
        self.confident_reprojection_px.extend(people.reprojection_px[conf].tolist())

    @property
    def mean_people(self) -> float:
        total = sum(k * v for k, v in self.people_histogram.items())
        return total / self.frames if self.frames else 0.0

    @property
    def mean_reprojection_px(self) -> float:
        return float(np.mean(self.reprojection_px)) if self.reprojection_px else float("nan")

    @property
    def median_confident_reprojection_px(self) -> float:
        e = self.confident_reprojection_px
        return float(np.median(e)) if e else float("nan")

    @property
    def fps_3d(self) -> float:
        return self.frames / self.seconds_3d if self.seconds_3d > 0 else float("nan")


def reconstruct_files(
    calib_path: str | Path,
    pose_dir: str | Path,
    out_path: str | Path,
    config: Config,
    on_frame: Callable[[int, int], None] | None = None,
) -> ReconstructionSummary:
    """Calibration + 2D keypoint folders -> 3D poses JSONL.

    on_frame(done, total) is called after each frame (progress display).
    """
    rig = load_calibration(calib_path)
    seq = read_pose_dir(pose_dir, rig.names)
    if len(seq.cameras) < 2:
        raise KeypointsError(
            f"{pose_dir}: keypoints found for {len(seq.cameras)} camera(s) "
            f"({', '.join(seq.cameras) or 'none'}); at least 2 calibrated cameras are needed"
        )
    if not seq.frames:
        raise KeypointsError(f"{pose_dir}: no keypoint files (*.json) in the camera folders")
    rig = rig.subset(seq.cameras)
    try:
        rec = Reconstructor(rig, config.reconstruction)
    except CalibrationError as e:
        raise CalibrationError(f"{calib_path}: {e}") from None
    summary = ReconstructionSummary(config.reconstruction.triangulation.mode, rig.names)
    total = len(seq)
    with PosesWriter(out_path, config.fps) as writer:
        for i, (frame, people2d) in enumerate(seq):
            t0 = time.perf_counter()
            summary.frames_read += bool(people2d)
            people = rec(frame, people2d)
            summary.seconds_3d += time.perf_counter() - t0
            writer.write(people)
            summary.add(people)
            if on_frame is not None:
                on_frame(i + 1, total)
    summary.skipped_files = [(str(p), why) for p, why in seq.skipped]
    if summary.skipped_files:
        logger.warning("%d keypoint file(s) skipped as malformed", len(summary.skipped_files))
    if summary.frames_read == 0:
        first = summary.skipped_files[0] if summary.skipped_files else ("", "")
        raise KeypointsError(
            f"{pose_dir}: none of the keypoint files could be read "
            f"({len(summary.skipped_files)} skipped; first: {first[0]}: {first[1]})"
        )
    return summary


def evaluate_poses_file(path: str | Path, scene: Scene) -> Metrics:
    """Accuracy of a 3D poses file against a simulated scene's ground truth."""
    return evaluate(load_people3d(path, len(scene.rig)), scene)
