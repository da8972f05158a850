"""Reconstruction runs: 2D keypoint files -> 3D poses, tracks, exports and zone events."""

from __future__ import annotations

import json
import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from stereopose.calibration.formats import load_calibration
from stereopose.config import Config
from stereopose.detection.openpose import read_pose_dir
from stereopose.errors import CalibrationError, KeypointsError, StereoposeError
from stereopose.fence import FenceMonitor, Site
from stereopose.fence.sinks import (
    CallbackSink,
    EventSink,
    JsonlSink,
    SqliteSink,
    WebhookSink,
)
from stereopose.io.exports import CsvExporter, TrcExporter
from stereopose.io.results import PosesWriter, load_people3d
from stereopose.reconstruction import Reconstructor
from stereopose.sim import Metrics, Scene, evaluate
from stereopose.tracking import Tracker, Trajectory
from stereopose.types import Event, People3D

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
    seconds_3d: float = 0.0  # association, triangulation and tracking
    frames_read: int = 0  # frames with at least one readable keypoint file
    tracking: bool = False
    trajectories: list[Trajectory] = field(default_factory=list)
    predicted: int = 0  # people output from prediction alone (bridged gaps)
    outputs: list[Path] = field(default_factory=list)
    events: dict[str, int] = field(default_factory=dict)  # event type -> count
    seconds_fences: float = 0.0

    def add(self, people: People3D) -> None:
        self.frames += 1
        self.predicted += int(people.predicted.sum())
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
    trc_dir: str | Path | None = None,
    csv_path: str | Path | None = None,
    tracks_path: str | Path | None = None,
    site: Site | None = None,
    events_path: str | Path | None = None,
    events_db: str | Path | None = None,
    webhook: str | None = None,
    on_events: Callable[[list[Event]], None] | None = None,
) -> ReconstructionSummary:
    """Calibration + 2D keypoint folders -> 3D poses JSONL (and TRC, CSV, trajectories).

    With tracking on (config.tracking.enabled) ids persist over time and joints are smoothed
    online. With a site, each frame's zone events go to events_path (JSON lines), events_db
    (SQLite, appended to), the webhook URL and on_events. on_frame(done, total) is called after
    each frame (progress display). Every output is closed properly when the run stops early
    (an error, Ctrl-C): what was written stays readable.
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
    if site is not None and not config.tracking.enabled:
        raise StereoposeError("zone events need tracking (person ids): drop --no-tracking")
    try:
        tracker = Tracker(rig, config) if config.tracking.enabled else None
        if tracker is not None:
            rec = tracker.reconstructor
        else:
            rec = Reconstructor(rig, config.reconstruction)
    except CalibrationError as e:
        raise CalibrationError(f"{calib_path}: {e}") from None
    step = tracker.update if tracker is not None else rec
    summary = ReconstructionSummary(
        config.reconstruction.triangulation.mode, rig.names, tracking=tracker is not None
    )
    total = len(seq)
    writer = PosesWriter(out_path, config.fps)
    summary.outputs.append(Path(out_path))
    sinks: list = [writer]
    event_sinks: list[EventSink] = []
    trc = csv_out = None
    fences = FenceMonitor(site, config.fps, config.tracking.max_lost_s) if site else None
    try:
        if fences is not None:
            event_sinks = _event_sinks(site, pose_dir, events_path, events_db, webhook, on_events)
            sinks.extend(event_sinks)
            summary.outputs.extend(Path(p) for p in (events_path, events_db) if p is not None)
        if csv_path is not None:
            csv_out = CsvExporter(csv_path, config.fps)
            sinks.append(csv_out)
            summary.outputs.append(Path(csv_path))
        if trc_dir is not None:
            trc = TrcExporter(trc_dir, config.fps)
        for i, (frame, people2d) in enumerate(seq):
            t0 = time.perf_counter()
            summary.frames_read += bool(people2d)
            people = step(frame, people2d)
            summary.seconds_3d += time.perf_counter() - t0
            writer.write(people)
            if fences is not None:
                t0 = time.perf_counter()
                events = fences.update(people)
                summary.seconds_fences += time.perf_counter() - t0
                for sink in event_sinks:
                    sink.write(events)
                for e in events:
                    summary.events[e.type] = summary.events.get(e.type, 0) + 1
            if csv_out is not None:
                csv_out.add(people)
            if trc is not None:
                trc.add(people)
            summary.add(people)
            if on_frame is not None:
                on_frame(i + 1, total)
    finally:
        for sink in sinks:
            sink.close()
        if trc is not None:
            summary.outputs.extend(trc.close())
        if tracker is not None:
            summary.trajectories = tracker.finish()
            if tracks_path is not None:
                write_trajectories(tracks_path, summary.trajectories)
                summary.outputs.append(Path(tracks_path))
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


def _event_sinks(site, pose_dir, events_path, events_db, webhook, on_events) -> list[EventSink]:
    sinks: list[EventSink] = []
    try:
        if events_path is not None:
            sinks.append(JsonlSink(events_path))
        if events_db is not None:
            sinks.append(SqliteSink(events_db, str(site.path or ""), str(pose_dir)))
        if webhook is not None:
            sinks.append(WebhookSink(webhook))
    except BaseException:
        for sink in sinks:
            sink.close()
        raise
    if on_events is not None:
        sinks.append(CallbackSink(on_events))
    return sinks


def write_trajectories(path: str | Path, trajectories: list[Trajectory]) -> None:
    """Per-person trajectory summaries as a JSON list."""
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(
            json.dumps([t.as_dict() for t in trajectories], indent=1) + "\n", encoding="utf-8"
        )
    except OSError as e:
        raise StereoposeError(f"{path}: cannot write trajectories: {e.strerror}") from None


def evaluate_poses_file(path: str | Path, scene: Scene) -> Metrics:
    """Accuracy of a 3D poses file against a simulated scene's ground truth."""
    return evaluate(load_people3d(path, len(scene.rig)), scene)


# -- calibration ---------------------------------------------------------------------------
