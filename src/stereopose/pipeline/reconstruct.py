"""Reconstruction runs: 2D keypoint files -> 3D poses, tracks, exports and zone events."""

from __future__ import annotations

import dataclasses
import json
import logging
import shutil
import threading
from collections.abc import Callable
from pathlib import Path

from stereopose.calibration.formats import load_calibration, save_calibration
from stereopose.config import Config
from stereopose.detection.openpose import read_pose_dir
from stereopose.errors import KeypointsError, StereoposeError
from stereopose.fence import Site, save_site
from stereopose.io.results import load_people3d
from stereopose.io.summary import RunSummary, write_summary
from stereopose.pipeline.loop import run_frames
from stereopose.pipeline.outputs import Outputs, check_outputs
from stereopose.pipeline.paths import (
    POSE_READS,
    TRC_PATTERNS,
    Place,
    check_places,
    flag,
    output_places,
    pattern_products,
    places,
    previous_outputs,
    remove_outputs,
)
from stereopose.pipeline.sources import KeypointFiles
from stereopose.sim import Metrics, Scene, evaluate
from stereopose.tickets.ticket import TICKET_JSON, Ticket, check_ticket_site
from stereopose.types import Event, Rig
from stereopose.zones.state_log import StateLogFile

logger = logging.getLogger(__name__)


def reconstruct_files(
    calib_path: str | Path,
    pose_dir: str | Path,
    out_path: str | Path | None,
    config: Config,
    on_frame: Callable[[int, int], None] | None = None,
    *,
    outputs: Outputs | None = None,
    site: Site | None = None,
    on_events: Callable[[list[Event]], None] | None = None,
    stop: threading.Event | None = None,
    config_path: str | Path | None = None,
    overwrite: bool = False,
    ticket: Ticket | None = None,
    zone_states: StateLogFile | None = None,
    **files: object,
) -> RunSummary:
    """Calibration + 2D keypoint folders -> 3D poses JSONL (and TRC, CSV, trajectories).

    out_path: the 3D poses file (None: not written). outputs: every other output (see
    pipeline.outputs.Outputs), or, as before, `files` by keyword: trc_dir, csv_path,
    tracks_path, events_path, events_db, webhook, two_way. With tracking on
    (config.tracking.enabled) ids persist over time and joints are smoothed online. With a
    site, each frame's zone events go to the event outputs and on_events; zone_states: the
    recording's switching log (zones.state_log; None: every energized zone live). on_frame(done,
    total) after each frame (progress display); `stop` ends the run after the current frame.
    Every output is closed properly when the run stops early (an error, Ctrl-C): what was
    written stays readable.

    Before anything is read or written, no output may be an input (the calibration, the
    keypoints folder or a file in it, the site, `config_path`: the configuration file read)
    or another output (pipeline.paths). A TRC folder holding a previous run's person files
    is refused unless `overwrite`, which removes them first.
    """
    if outputs is None:
        outputs = Outputs.from_keywords(out_path, **files)
    elif files:
        raise TypeError("give the outputs either as `outputs` or by keyword, not both")
    elif out_path is not None:
        outputs = dataclasses.replace(outputs, poses=Path(out_path))
    inputs = places(
        ("--calib", calib_path),
        ("--config", config_path),
        ("--site", site.path if site is not None else None),
    )
    inputs.append(Place("--pose", Path(pose_dir), reads=POSE_READS))
    check_places(inputs, output_places(outputs, flag))
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
    check_outputs(config, site, outputs)
    check_ticket_site(ticket, site)
    if outputs.trc_dir is not None:
        trc = Place("--trc folder", outputs.trc_dir)
        remove_outputs(previous_outputs(trc, pattern_products(TRC_PATTERNS), overwrite, inputs))
    source = KeypointFiles(seq, config.fps)
    on_step = None if on_frame is None else (lambda done, total, fps: on_frame(done, total))
    summary = run_frames(
        rig,
        config,
        source,
        outputs,
        site,
        calib_path=str(calib_path),
        label=str(pose_dir),
        on_events=on_events,
        stop=stop,
        on_step=on_step,
        ticket=ticket,
        zone_states=zone_states,
    )
    if summary.frames_read == 0:
        first = summary.skipped_files[0] if summary.skipped_files else ("", "")
        raise KeypointsError(
            f"{pose_dir}: none of the keypoint files could be read "
            f"({len(summary.skipped_files)} skipped; first: {first[0]}: {first[1]})"
        )
    return summary


def save_inputs(out_dir: Path, rig: Rig, site: Site | None, ticket: Ticket | None = None) -> None:
    """The calibration, site and ticket a run used, which the reports are rebuilt from (a
    ticket of an earlier run in the folder removed)."""
    save_calibration(out_dir / "calib.toml", rig)
    if site is not None:
        save_site(out_dir / "site.toml", site)
    path = out_dir / TICKET_JSON
    if ticket is None:
        path.unlink(missing_ok=True)
        return
    try:
        path.write_text(json.dumps(ticket.to_dict(), indent=1), encoding="utf-8")
    except OSError as e:
        raise StereoposeError(f"{path}: cannot write the ticket: {e.strerror}") from None


def write_reconstruction_report(
    out_dir: Path,
    summary: RunSummary,
    calib_path: Path,
    site: Site | None,
    poses_path: Path,
    events_path: Path | None = None,
    ticket: Ticket | None = None,
) -> Path:
    """A run folder and its report for a reconstruction from keypoint files (no cameras)."""
    from stereopose.viz.report import write_report

    out_dir = Path(out_dir)
    for src, name in ((poses_path, "poses3d.jsonl"), (events_path, "events.jsonl")):
        if src is not None and Path(src).resolve() != (out_dir / name).resolve():
            shutil.copyfile(src, out_dir / name)
    save_inputs(out_dir, load_calibration(calib_path), site, ticket)
    write_summary(out_dir / "summary.json", summary)
    return write_report(out_dir)


def evaluate_poses_file(path: str | Path, scene: Scene) -> Metrics:
    """Accuracy of a 3D poses file against a simulated scene's ground truth."""
    return evaluate(load_people3d(path, len(scene.rig)), scene)
