"""File sinks: 3D poses JSON lines, joints CSV, per-person TRC, trajectories, and the
two-way smoothing of the CSV and TRC exports."""

from __future__ import annotations

import json
import logging
from collections.abc import Callable, Sequence
from pathlib import Path

from stereopose.errors import OutputError
from stereopose.io.exports import CsvExporter, TrcExporter
from stereopose.io.results import PosesWriter
from stereopose.io.sinks.base import ClosesOnce, FrameResult, Sink, close_all
from stereopose.io.writing import probe_folder, probe_output
from stereopose.tracking.positioning import Trajectory
from stereopose.types import People3D

logger = logging.getLogger(__name__)


class PosesSink(ClosesOnce):
    """The 3D poses JSON lines, one flushed line per frame (io.results.PosesWriter)."""

    stage = "write"

    def __init__(self, path: str | Path, fps: float) -> None:
        self.writer = PosesWriter(path, fps)

    def write(self, frame: FrameResult) -> None:
        self.writer.write(frame.people3d, frame.postures)

    def _close(self) -> list[Path]:
        self.writer.close()
        return [self.writer.path]


class CsvSink(ClosesOnce):
    """Every reconstructed joint as a CSV row, flushed every frame (io.exports.CsvExporter)."""

    stage = "write"

    def __init__(self, path: str | Path, fps: float) -> None:
        self.exporter = CsvExporter(path, fps)

    def write(self, frame: FrameResult) -> None:
        self.exporter.add(frame.people3d)

    def _close(self) -> list[Path]:
        self.exporter.close()
        return [self.exporter.path]


class TrcSink(ClosesOnce):
    """One TRC file per person, streamed (io.exports.TrcExporter); the folder is made and
    tried at once, since the files come as people do."""

    stage = "write"

    def __init__(self, out_dir: str | Path, fps: float, idle_frames: int | None = None) -> None:
        probe_folder(out_dir, "TRC files")
        self.exporter = TrcExporter(out_dir, fps, idle_frames)

    def write(self, frame: FrameResult) -> None:
        self.exporter.add(frame.people3d)

    def _close(self) -> list[Path]:
        return self.exporter.close()


class TracksSink(ClosesOnce):
    """The per-person trajectory summaries (tracks.json), written at close from
    ``trajectories()`` (the 3D stage's: one small record per person, none per frame); its
    folder is tried at once."""

    stage = "write"

    def __init__(self, path: str | Path, trajectories: Callable[[], list[Trajectory]]) -> None:
        self.path = Path(path)
        probe_output(self.path, "trajectories")
        self.trajectories = trajectories

    def write(self, frame: FrameResult) -> None:
        pass

    def _close(self) -> list[Path]:
        write_trajectories(self.path, self.trajectories())
        return [self.path]


class TwoWaySink(ClosesOnce):
    """Holds every frame's 3D people and, at close, hands them smoothed both ways over each
    track (``smooth``: the 3D stage's two_way) to ``sinks`` (the CSV and TRC exports).

    The one output whose memory grows with the run: the smoother needs each track to its end.
    If smoothing fails, the online people are written instead (the exports are never lost).
    """

    stage = "write"

    def __init__(
        self, sinks: Sequence[Sink], smooth: Callable[[list[People3D]], list[People3D]]
    ) -> None:
        self.sinks = list(sinks)
        self.smooth = smooth
        self._frames: list[FrameResult] = []

    @property
    def frames_kept(self) -> int:
        return len(self._frames)

    def write(self, frame: FrameResult) -> None:
        self._frames.append(FrameResult(frame.frame, frame.t, {}, frame.people3d))

    def _close(self) -> list[Path]:
        frames, self._frames = self._frames, []
        try:
            people = self.smooth([f.people3d for f in frames]) if frames else []
        except Exception:  # never lose the exports: the online joints are written instead
            logger.exception("two-way smoothing failed; exports hold the online joints")
            people = [f.people3d for f in frames]
        error: BaseException | None = None
        try:
            for f, p in zip(frames, people, strict=True):
                for sink in self.sinks:
                    sink.write(FrameResult(f.frame, f.t, {}, p))
        except BaseException as e:
            error = e
        paths, failed = close_all(self.sinks)
        if error is not None:
            raise error
        if failed is not None:
            raise failed
        return paths


def write_trajectories(path: str | Path, trajectories: list[Trajectory]) -> None:
    """Per-person trajectory summaries as a JSON list."""
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(
            json.dumps([t.as_dict() for t in trajectories], indent=1) + "\n", encoding="utf-8"
        )
    except OSError as e:
        raise OutputError(f"{path}: cannot write trajectories: {e.strerror}") from None
