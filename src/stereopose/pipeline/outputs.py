"""Which outputs a run writes, and the one function that opens them as sinks.

`Outputs` says where each output goes (None: not written); `Outputs.run_folder` derives it from
a run folder and the configuration's [outputs]; `reconstruct` builds it from its options.
`open_outputs` opens every sink it names, in the order the frame loop closes them: the files
and event outputs, the overlay videos, the statistics, then the summary and the report, which
read what the others wrote.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from stereopose.config import Config, OutputConfig
from stereopose.errors import StereoposeError
from stereopose.extras import require
from stereopose.fence import Site
from stereopose.io.datafolder import EVENTS_DB
from stereopose.io.sinks import (
    CallbackSink,
    CameraStatsSink,
    CsvSink,
    JsonlSink,
    PosesSink,
    Sink,
    SqliteSink,
    SummarySink,
    TracksSink,
    TrcSink,
    TwoWaySink,
    WebhookSink,
    close_all,
)
from stereopose.io.sinks.base import ClosesOnce, FrameResult, Guarded
from stereopose.io.source import shown_url
from stereopose.io.summary import RunSummary
from stereopose.io.writing import probe_output
from stereopose.types import Event, Rig

if TYPE_CHECKING:
    from stereopose.pipeline.stage3d import Stage3D

# reconstruct_files' keyword names for the fields of Outputs
KEYWORDS = {
    "trc_dir": "trc_dir",
    "csv_path": "csv",
    "tracks_path": "tracks",
    "events_path": "events",
    "events_db": "events_db",
    "webhook": "webhook",
    "two_way": "two_way",
}


@dataclass(frozen=True)
class Outputs:
    """Where a run's outputs go; None: not written.

    events, events_db, webhook: zone events (only with a site). two_way: the CSV and TRC
    exports are smoothed both ways over each track and written at the end (the one output
    that holds the whole run in memory). overlays_dir: one video per camera (cameras only).
    summary: summary.json. report_dir: report.html, built from that folder (which must hold
    summary.json, calib.toml and the poses as a run folder does).
    """

    poses: Path | None = None
    events: Path | None = None
    events_db: Path | None = None
    webhook: str | None = None
    trc_dir: Path | None = None
    csv: Path | None = None
    tracks: Path | None = None
    two_way: bool = False
    overlays_dir: Path | None = None
    overlay_scale: float = 0.5
    summary: Path | None = None
    report_dir: Path | None = None

    @classmethod
    def run_folder(cls, out_dir: str | Path, o: OutputConfig, site: Site | None) -> Outputs:
        """The outputs of `stereopose run` in its folder, as [outputs] asks."""
        out = Path(out_dir)
        events = site is not None and o.events
        return cls(
            poses=out / "poses3d.jsonl" if o.poses else None,
            events=out / "events.jsonl" if events else None,
            events_db=out / EVENTS_DB if events else None,
            webhook=o.webhook,
            trc_dir=out / "trc" if o.trc else None,
            csv=out / "joints.csv" if o.csv else None,
            tracks=out / "tracks.json",
            two_way=o.two_way,
            overlays_dir=out / "overlays" if o.overlays else None,
            overlay_scale=o.overlay_scale,
            summary=out / "summary.json",
            report_dir=out if o.report else None,
        )

    @classmethod
    def from_keywords(cls, poses: str | Path | None, **kw: object) -> Outputs:
        """From reconstruct_files' keywords (trc_dir, csv_path, tracks_path, events_path,
        events_db, webhook, two_way); None values are left out."""
        unknown = sorted(set(kw) - set(KEYWORDS))
        if unknown:
            raise TypeError(f"unknown output keyword(s): {', '.join(unknown)}")
        values: dict = {KEYWORDS[k]: v for k, v in kw.items() if v is not None}
        for name in ("trc_dir", "csv", "tracks", "events", "events_db"):
            if name in values:
                values[name] = Path(values[name])
        return cls(poses=Path(poses) if poses is not None else None, **values)


def check_outputs(config: Config, site: Site | None, outputs: Outputs) -> None:
    """What the outputs need of the 3D stage, checked before anything is opened."""
    how = 'drop --no-tracking, or set [tracking] memory = "tracker"'
    if site is not None and not config.tracking.ids:
        raise StereoposeError(f"zone events need tracking (person ids): {how}")
    if outputs.two_way and not config.tracking.ids:
        raise StereoposeError(f"two-way smoothing needs tracking (person ids): {how}")


class ReportSink(ClosesOnce):
    """report.html, built at close from the run folder (after summary.json); none after an
    error. Its folder is tried at once."""

    stage = "write"

    def __init__(self, run_dir: Path, summary: RunSummary) -> None:
        self.run_dir, self.summary = Path(run_dir), summary
        self.path = self.run_dir / "report.html"
        # before the run starts, not at its end
        require("plotly", "report", "the HTML report (report.html)", "or [outputs] report = false")
        probe_output(self.path, "the report")

    def write(self, frame: FrameResult) -> None:
        pass

    def _close(self) -> list[Path]:
        if self.summary.error is not None:
            return []
        from stereopose.viz.report import write_report

        return [write_report(self.run_dir)]


def _event_sinks(
    o: Outputs,
    site: Site,
    source: str,
    on_events: Callable[[list[Event]], None] | None,
    guard: Callable[[Sink, object], Sink],
) -> list[Sink]:
    sinks: list[Sink] = []
    if o.events is not None:
        sinks.append(guard(JsonlSink(o.events), o.events))
    if o.events_db is not None:
        sinks.append(guard(SqliteSink(o.events_db, str(site.path or ""), source), o.events_db))
    if o.webhook is not None:
        sinks.append(guard(WebhookSink(o.webhook), shown_url(o.webhook)))
    if on_events is not None:
        sinks.append(guard(CallbackSink(on_events), "the events shown"))
    return sinks


def open_outputs(
    outputs: Outputs,
    *,
    rig: Rig,
    config: Config,
    summary: RunSummary,
    stage: Stage3D,
    site: Site | None = None,
    source: str = "",
    on_events: Callable[[list[Event]], None] | None = None,
) -> list[Sink]:
    """Every sink `outputs` names, in closing order (see the module); `stage` is the 3D stage
    (its trajectories and two-way smoother). Event outputs only with a site.

    Each output is opened, or its folder tried, now: if one cannot be, those already open are
    closed and its OutputError is raised, before any work. Later, an output that fails (disk
    full, folder gone) stops alone (io.sinks.base.Guarded): the run and the other outputs go
    on, and `summary.failed_outputs` names it and why.
    """
    o, fps = outputs, config.fps
    sinks: list[Sink] = []

    def guard(sink: Sink, label: object) -> Sink:
        return Guarded(sink, str(label), summary.failed_outputs)

    try:
        if o.poses is not None:
            sinks.append(guard(PosesSink(o.poses, fps), o.poses))
        if site is not None:
            sinks += _event_sinks(o, site, source, on_events, guard)
        exports: list[Sink] = []
        if o.csv is not None:
            exports.append(guard(CsvSink(o.csv, fps), o.csv))
        if o.trc_dir is not None:  # a track unseen this long has ended: its file is closed
            idle = math.ceil(config.tracking.max_lost_s * fps) + 2
            exports.append(guard(TrcSink(o.trc_dir, fps, idle_frames=idle), o.trc_dir))
        if o.two_way and exports:
            sinks.append(guard(TwoWaySink(exports, stage.two_way), "the two-way exports"))
        else:
            sinks += exports
        if o.overlays_dir is not None:
            from stereopose.pipeline.overlays import OverlaySink

            overlays = OverlaySink(rig, o.overlays_dir, fps, o.overlay_scale)
            sinks.append(guard(overlays, o.overlays_dir))
        sinks.append(guard(CameraStatsSink(rig, summary.per_camera), "the camera statistics"))
        if o.tracks is not None and stage.tracking:
            sinks.append(guard(TracksSink(o.tracks, stage.trajectories), o.tracks))
        sinks.append(guard(SummarySink(summary, o.summary), o.summary or "the run summary"))
        if o.report_dir is not None:
            report = ReportSink(o.report_dir, summary)
            sinks.append(guard(report, report.path))
    except BaseException:
        close_all(sinks)
        raise
    return sinks
