"""Reconstruction runs: 2D keypoint files -> 3D poses, tracks, exports and zone events."""

from __future__ import annotations

import logging
from collections.abc import Callable
from pathlib import Path

from stereopose.calibration.formats import load_calibration
from stereopose.config import Config
from stereopose.detection.openpose import read_pose_dir
from stereopose.errors import KeypointsError
from stereopose.fence import Site
from stereopose.io.results import load_people3d
from stereopose.pipeline.stages import Back3D, ReconstructionSummary
from stereopose.sim import Metrics, Scene, evaluate
from stereopose.types import Event

logger = logging.getLogger(__name__)


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
    two_way: bool = False,
) -> ReconstructionSummary:
    """Calibration + 2D keypoint folders -> 3D poses JSONL (and TRC, CSV, trajectories).

    With tracking on (config.tracking.enabled) ids persist over time and joints are smoothed
    online. With a site, each frame's zone events go to events_path (JSON lines), events_db
    (SQLite, appended to), the webhook URL and on_events. on_frame(done, total) is called after
    each frame (progress display). two_way: the TRC and CSV exports are smoothed both ways
    over each track and written at the end (see Back3D). Every output is closed properly when
    the run stops early (an error, Ctrl-C): what was written stays readable.
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
    back = Back3D(
        rig,
        config,
        out_path,
        calib_path=calib_path,
        source=str(pose_dir),
        trc_dir=trc_dir,
        csv_path=csv_path,
        tracks_path=tracks_path,
        site=site,
        events_path=events_path,
        events_db=events_db,
        webhook=webhook,
        on_events=on_events,
        two_way=two_way,
    )
    summary = back.summary
    total = len(seq)
    try:
        for i, (frame, people2d) in enumerate(seq):
            summary.frames_read += bool(people2d)
            back.step(frame, people2d)
            if on_frame is not None:
                on_frame(i + 1, total)
    finally:
        back.close()
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


# -- calibration ---------------------------------------------------------------------------
