"""Wires the stages together; the only module that knows them all."""

from __future__ import annotations

import json
import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from stereopose.calibration.board import Board
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
from stereopose.types import Event, People3D, Rig

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


@dataclass
class IntrinsicsRun:
    results: dict  # camera -> IntrinsicsResult
    detections: dict  # camera -> [Detection]
    outputs: list[Path] = field(default_factory=list)


def _camera_folders(images: Path) -> list[tuple[str, Path]]:
    """(camera name, folder or video) of a folder holding one camera's photos, or one
    sub-folder (or video) per camera."""
    from stereopose.calibration.intrinsics import IMAGE_SUFFIXES, VIDEO_SUFFIXES, camera_name

    if images.is_file():
        return [(camera_name(images.stem), images)]
    if not images.is_dir():
        raise CalibrationError(f"{images}: not a folder of photos or a video file")
    subs = sorted(
        p
        for p in images.iterdir()
        if p.is_dir() or (p.is_file() and p.suffix.lower() in VIDEO_SUFFIXES)
    )
    photos = [p for p in images.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES]
    if photos or not subs:
        return [(camera_name(images.name), images)]
    return [(camera_name(p.stem if p.is_file() else p.name), p) for p in subs]


def calibrate_intrinsics_dir(
    images: str | Path,
    board: Board,
    out: str | Path,
    k3: bool = False,
    report_dir: str | Path | None = None,
    on_camera: Callable[[str], None] | None = None,
) -> IntrinsicsRun:
    """Intrinsics of every camera found under `images`, written to `out` (.toml, or an
    OpenCV YAML folder / .yml); a PNG report in report_dir."""
    from stereopose.calibration.intrinsics import calibrate_intrinsics, detect_all, iter_images

    run = IntrinsicsRun({}, {})
    for name, folder in _camera_folders(Path(images)):
        if on_camera is not None:
            on_camera(name)
        dets = detect_all(iter_images(folder), board)
        run.detections[name] = dets
        run.results[name] = calibrate_intrinsics(name, dets, board, k3=k3)
    rig = Rig(tuple(r.camera for r in run.results.values()))
    run.outputs.append(_save_rig(out, rig, {"intrinsics_only": True}))
    if report_dir is not None:
        from stereopose.viz.calibration import intrinsics_png

        Path(report_dir).mkdir(parents=True, exist_ok=True)
        run.outputs.append(
            intrinsics_png(Path(report_dir) / "intrinsics.png", run.results, run.detections)
        )
    return run


def _save_rig(out: str | Path, rig: Rig, metadata: dict) -> Path:
    from stereopose.calibration.formats import save_calibration
    from stereopose.calibration.opencv_yaml import write_opencv_yaml

    out = Path(out)
    if out.suffix.lower() == ".toml":
        out.parent.mkdir(parents=True, exist_ok=True)
        save_calibration(out, rig, metadata=metadata)
        return out
    return write_opencv_yaml(out, rig)[0]


@dataclass
class ExtrinsicsRun:
    result: object  # ExtrinsicsResult
    found: dict  # camera -> {position: found?}
    outputs: list[Path] = field(default_factory=list)


def calibrate_extrinsics_dir(
    images: str | Path,
    intrinsics: str | Path,
    board: Board,
    out: str | Path,
    floor: str | None = None,
    origin_m: tuple[float, float] = (0.0, 0.0),
    yaw_deg: float = 0.0,
    refine_intrinsics: bool = False,
    report_dir: str | Path | None = None,
    on_camera: Callable[[str], None] | None = None,
    intrinsics_images: str | Path | None = None,
) -> ExtrinsicsRun:
    """The rig from synchronised board photos: `images` holds one sub-folder per camera with
    the same file name per board position (the position's name is the file's stem).

    intrinsics_images: the cameras' own board photos (as for the intrinsics), added to the
    adjustment as positions seen by one camera: with refine_intrinsics, focal lengths and
    distortion are then refined from both sets at once."""
    from stereopose.calibration.extrinsics import calibrate_extrinsics
    from stereopose.calibration.intrinsics import detect_all, iter_images

    rig = load_calibration(intrinsics, min_cameras=1)
    cams = {c.name: c for c in rig}
    corners: dict[str, dict[str, np.ndarray]] = {}
    found: dict[str, dict[str, bool]] = {}
    folders = _camera_folders(Path(images))
    if len(folders) < 2:
        raise CalibrationError(f"{images}: needs one sub-folder of photos per camera (>= 2)")
    for name, folder in folders:
        if name not in cams:
            raise CalibrationError(
                f"{folder}: camera {name!r} has no intrinsics in {intrinsics} "
                f"(cameras there: {', '.join(cams)})"
            )
        if on_camera is not None:
            on_camera(name)
        dets = detect_all(iter_images(folder), board)
        for d in dets:
            if d.image_size is not None and tuple(d.image_size) != tuple(
                int(v) for v in cams[name].size
            ):
                raise CalibrationError(
                    f"{folder}/{d.name}: image size {d.image_size} differs from camera "
                    f"{name}'s {tuple(int(v) for v in cams[name].size)} in {intrinsics}"
                )
        corners[name] = {Path(d.name).stem: d.corners.points for d in dets if d.corners}
        found[name] = {Path(d.name).stem: d.corners is not None for d in dets}
    if intrinsics_images is not None:
        for name, folder in _camera_folders(Path(intrinsics_images)):
            if name not in corners:
                continue
            if on_camera is not None:
                on_camera(f"{name} (intrinsics photos)")
            for d in detect_all(iter_images(folder), board):
                if d.corners is not None:
                    corners[name][f"{name}:{Path(d.name).stem}"] = d.corners.points
    result = calibrate_extrinsics(cams, corners, board, floor, origin_m, yaw_deg, refine_intrinsics)
    run = ExtrinsicsRun(result, found)
    run.outputs.append(_save_rig(out, result.rig, {"rms_px": round(result.rms_px, 4)}))
    if report_dir is not None:
        from stereopose.viz.calibration import extrinsics_png

        Path(report_dir).mkdir(parents=True, exist_ok=True)
        run.outputs.append(
            extrinsics_png(
                Path(report_dir) / "extrinsics.png",
                result.rig,
                board,
                result.board_poses,
                result.residuals_px,
            )
        )
    return run
