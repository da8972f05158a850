"""The 3D back end of a run and its outputs: 2D people -> 3D people, tracks, zone events, files.

``Back3D`` is shared by ``reconstruct`` (keypoint files) and ``run`` (cameras): one ``step`` per
frame, ``close`` once (also after an error or Ctrl-C: what was written stays readable).
"""

from __future__ import annotations

import json
import logging
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from stereopose.config import Config
from stereopose.errors import StereoposeError
from stereopose.fence import FenceMonitor, Site
from stereopose.fence.sinks import CallbackSink, EventSink, JsonlSink, SqliteSink, WebhookSink
from stereopose.io.exports import CsvExporter, TrcExporter
from stereopose.io.results import PosesWriter
from stereopose.pipeline.stage3d import Stage3D
from stereopose.tracking import Trajectory
from stereopose.types import Event, People2D, People3D, Rig

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
    seconds_write: float = 0.0

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


class Back3D:
    """Association, triangulation, tracking, fences and the writers of one run.

    out_path: the 3D poses JSONL (None: not written). With a site, each frame's zone events go
    to events_path (JSON lines), events_db (SQLite, appended to), the webhook URL and on_events.
    two_way: the TRC and CSV exports are written at the end, from joints smoothed both ways
    over each track (tracking.offline); the poses file and the events stay online.
    """

    def __init__(
        self,
        rig: Rig,
        config: Config,
        out_path: str | Path | None,
        *,
        calib_path: str | Path = "",
        source: str = "",
        trc_dir: str | Path | None = None,
        csv_path: str | Path | None = None,
        tracks_path: str | Path | None = None,
        site: Site | None = None,
        events_path: str | Path | None = None,
        events_db: str | Path | None = None,
        webhook: str | None = None,
        on_events: Callable[[list[Event]], None] | None = None,
        two_way: bool = False,
    ) -> None:
        if site is not None and not config.tracking.enabled:
            raise StereoposeError("zone events need tracking (person ids): drop --no-tracking")
        if two_way and not config.tracking.enabled:
            raise StereoposeError("two-way smoothing needs tracking (person ids)")
        self.stage = Stage3D(rig, config, record=two_way, calib_path=str(calib_path))
        self.tracker = self.stage if self.stage.tracking else None
        self.rig = rig
        self.tracks_path = tracks_path
        self.summary = ReconstructionSummary(
            config.reconstruction.triangulation.mode, rig.names, tracking=self.tracker is not None
        )
        self.sinks: list = []
        self.event_sinks: list[EventSink] = []
        self.trc: TrcExporter | None = None
        self.csv: CsvExporter | None = None
        self.writer: PosesWriter | None = None
        self.fences = FenceMonitor(site, config.fps, config.tracking.max_lost_s) if site else None
        self._closed = False
        self.two_way = two_way
        self._frames: list[People3D] = []  # the online output, kept for two-way exports
        try:
            if out_path is not None:
                self.writer = PosesWriter(out_path, config.fps)
                self.sinks.append(self.writer)
                self.summary.outputs.append(Path(out_path))
            if self.fences is not None:
                self._open_event_sinks(site, source, events_path, events_db, webhook, on_events)
            if csv_path is not None:
                self.csv = CsvExporter(csv_path, config.fps)
                self.sinks.append(self.csv)
                self.summary.outputs.append(Path(csv_path))
            if trc_dir is not None:
                self.trc = TrcExporter(trc_dir, config.fps)
        except BaseException:
            self.close()
            raise

    def _open_event_sinks(self, site, source, events_path, events_db, webhook, on_events) -> None:
        if events_path is not None:
            self.event_sinks.append(JsonlSink(events_path))
        if events_db is not None:
            self.event_sinks.append(SqliteSink(events_db, str(site.path or ""), str(source)))
        if webhook is not None:
            self.event_sinks.append(WebhookSink(webhook))
        if on_events is not None:
            self.event_sinks.append(CallbackSink(on_events))
        self.sinks.extend(self.event_sinks)
        self.summary.outputs.extend(Path(p) for p in (events_path, events_db) if p is not None)

    def step(self, frame: int, people2d: Mapping[str, People2D]) -> tuple[People3D, list[Event]]:
        """One frame: the 3D people (ids, smoothed joints, positions) and its zone events."""
        s = self.summary
        t0 = time.perf_counter()
        people = self.stage.step(frame, people2d)
        t1 = time.perf_counter()
        s.seconds_3d += t1 - t0
        events: list[Event] = []
        if self.fences is not None:
            events = self.fences.update(people)
            for e in events:
                s.events[e.type] = s.events.get(e.type, 0) + 1
        t2 = time.perf_counter()
        s.seconds_fences += t2 - t1
        if self.writer is not None:
            self.writer.write(people)
        for sink in self.event_sinks:
            sink.write(events)
        if self.two_way and (self.csv is not None or self.trc is not None):
            self._frames.append(people)
        else:
            self._export(people)
        s.add(people)
        s.seconds_write += time.perf_counter() - t2
        return people, events

    def _export(self, people: People3D) -> None:
        if self.csv is not None:
            self.csv.add(people)
        if self.trc is not None:
            self.trc.add(people)

    def close(self) -> None:
        """Close every output (once): flushes files, ends tracks, writes trajectories."""
        if self._closed:
            return
        self._closed = True
        if self._frames:
            try:
                frames = self.tracker.two_way(self._frames)
            except Exception:  # never lose the exports: the online joints are written instead
                logger.exception("two-way smoothing failed; exports hold the online joints")
                frames = self._frames
            for people in frames:
                self._export(people)
            self._frames = []
        for sink in self.sinks:
            sink.close()
        if self.trc is not None:
            self.summary.outputs.extend(self.trc.close())
        if self.tracker is not None:
            self.summary.trajectories = self.stage.trajectories()
            if self.tracks_path is not None:
                write_trajectories(self.tracks_path, self.summary.trajectories)
                self.summary.outputs.append(Path(self.tracks_path))


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
