"""What a run did: one summary for every frame loop (keypoint files, cameras, the service).

It holds running aggregates only (counts, sums, fixed-size histograms: see io.aggregates), so
its size does not grow with the number of frames; `as_dict` is the content of summary.json.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from stereopose.errors import StereoposeError
from stereopose.io.aggregates import RunningStats
from stereopose.tracking.positioning import Trajectory
from stereopose.types import Event, People3D

# the stages a frame goes through, timed apart; keypoint files are read instead of decoded
CAMERA_STAGES = ("decode", "detect", "3d", "fences", "write", "overlays")
FILE_STAGES = ("read", "3d", "fences", "write")


def _finite(x: float) -> float | None:
    return x if math.isfinite(x) else None


@dataclass
class CameraStats:
    """One camera's frames, detections and the reprojection error (pixels) of the output
    joints against the detections they rest on (median to 0.025 px, see RunningStats)."""

    frames: int = 0
    detections: int = 0
    reprojection: RunningStats = field(default_factory=RunningStats, repr=False)

    def as_dict(self) -> dict:
        e = self.reprojection
        return {
            "frames": self.frames,
            "detections_per_frame": self.detections / self.frames if self.frames else 0.0,
            "reprojection_median_px": _finite(e.median),
            "reprojection_mean_px": _finite(e.mean),
            "joints_compared": e.count,
        }


@dataclass
class RunSummary:
    """What a run did, for the terminal, summary.json, the report and the benchmarks.

    seconds: per stage (`stages`), excluding `load_s_3d`, the time the 3D stage's compiled
    loops took to load once before the first frame; wall_s: the frame loop's time, from the
    first frame on. reprojection: every output joint's reprojection error (pixels of the
    undistorted image) over the views it was triangulated from; confident_reprojection: those
    of joints with conf > 0.5. two_way_frames: frames held for the two-way smoother (the one
    output that keeps a whole run in memory: it needs every track to its end).
    """

    cameras: tuple[str, ...]
    stages: tuple[str, ...] = CAMERA_STAGES
    mode: str = ""
    tracking: bool = False
    out_dir: Path | None = None
    config_path: Path | None = None  # None: a reconstruction from keypoint files
    live: bool = False
    # live cameras: wall-clock time (seconds since 1970) of t = 0; a record's wall time is this + t
    clock_start_epoch: float | None = None
    fps_input: float = 0.0
    frames: int = 0
    frames_read: int | None = None  # keypoint input: frames with a readable keypoint file
    seconds: dict[str, float] = field(default_factory=dict)
    load_s_3d: float = 0.0
    wall_s: float = 0.0
    people_histogram: dict[int, int] = field(default_factory=dict)  # people per frame -> frames
    joints_reconstructed: int = 0
    predicted: int = 0  # people output from prediction alone (bridged gaps)
    reprojection: RunningStats = field(default_factory=RunningStats, repr=False)
    confident_reprojection: RunningStats = field(default_factory=RunningStats, repr=False)
    per_camera: dict[str, CameraStats] = field(default_factory=dict)
    sources: dict[str, dict] = field(default_factory=dict)  # live cameras: dropped, reconnects
    pipeline: dict[str, float | None] = field(default_factory=dict)  # pipelined detection's figures
    # detection in regions, by camera (detection.regional.CameraRegions); empty: whole frames
    regions: dict[str, dict[str, float | int]] = field(default_factory=dict)
    # the detector's backend and precision, and why (detection.Choice); empty: not known
    detector: dict[str, str] = field(default_factory=dict)
    # each camera's light at the end (detection.light.LightWatch.figures); empty: not measured
    light: dict[str, dict] = field(default_factory=dict)
    # carried steps, by camera: steps detected and carried (detection.carry); empty: none
    carry: dict[str, dict[str, int]] = field(default_factory=dict)
    events: dict[str, int] = field(default_factory=dict)  # event type -> count
    trajectories: list[Trajectory] = field(default_factory=list)
    skipped_files: list[tuple[str, str]] = field(default_factory=list)  # malformed inputs
    two_way_frames: int = 0
    outputs: list[Path] = field(default_factory=list)
    failed_outputs: dict[str, str] = field(default_factory=dict)  # output -> why not written
    interrupted: bool = False
    error: str | None = None

    def __post_init__(self) -> None:
        for k in self.stages:
            self.seconds.setdefault(k, 0.0)

    def add(self, people: People3D, events: Sequence[Event] = ()) -> None:
        """One frame's output people and zone events."""
        self.frames += 1
        self.predicted += 0 if people.predicted is None else int(people.predicted.sum())
        n = len(people)
        self.people_histogram[n] = self.people_histogram.get(n, 0) + 1
        ok = np.isfinite(people.reprojection_px)
        self.joints_reconstructed += int(ok.sum())
        self.reprojection.add(people.reprojection_px[ok])
        self.confident_reprojection.add(people.reprojection_px[ok & (people.conf > 0.5)])
        for e in events:
            self.events[e.type] = self.events.get(e.type, 0) + 1

    # -- derived figures -----------------------------------------------------------------

    @property
    def steps(self) -> int:
        return self.frames

    @property
    def fps(self) -> float:
        return self.frames / self.wall_s if self.wall_s > 0 else 0.0

    def stage_fps(self) -> dict[str, float | None]:
        return {k: (self.frames / v if v > 0 else None) for k, v in self.seconds.items()}

    @property
    def seconds_3d(self) -> float:
        return self.seconds.get("3d", 0.0)

    @property
    def seconds_fences(self) -> float:
        return self.seconds.get("fences", 0.0)

    @property
    def seconds_write(self) -> float:
        return self.seconds.get("write", 0.0)

    @property
    def fps_3d(self) -> float:
        """Frames per second of the 3D stage (association, triangulation, tracking), loading
        the compiled loops excluded."""
        return self.frames / self.seconds_3d if self.seconds_3d > 0 else float("nan")

    @property
    def mean_people(self) -> float:
        total = sum(k * v for k, v in self.people_histogram.items())
        return total / self.frames if self.frames else 0.0

    people_per_frame = mean_people

    @property
    def mean_reprojection_px(self) -> float:
        return self.reprojection.mean

    @property
    def median_confident_reprojection_px(self) -> float:
        return self.confident_reprojection.median

    @property
    def reprojection_median_px(self) -> float | None:
        """Median over every camera of the output joints against their detections; without
        per-camera figures, the median of the confident joints' errors."""
        pooled = RunningStats()
        for c in self.per_camera.values():
            pooled.merge(c.reprojection)
        value = pooled.median if pooled.count else self.confident_reprojection.median
        return _finite(value)

    @property
    def camera_stats(self) -> dict[str, CameraStats]:
        return self.per_camera

    @property
    def people(self) -> list[dict]:
        return [t.as_dict() for t in self.trajectories]

    def as_dict(self) -> dict:
        """The content of summary.json."""
        return {
            "config": str(self.config_path) if self.config_path else None,
            "cameras": list(self.cameras),
            "mode": self.mode,
            "tracking": self.tracking,
            "live": self.live,
            "clock_start_epoch": self.clock_start_epoch,
            "fps_input": self.fps_input,
            "frames": self.frames,
            "frames_read": self.frames_read,
            "wall_s": self.wall_s,
            "fps": self.fps,
            "load_s_3d": self.load_s_3d,
            "seconds_per_stage": dict(self.seconds),
            "fps_per_stage": self.stage_fps(),
            "fps_3d": _finite(self.fps_3d),
            "people_per_frame": self.people_per_frame,
            "people_histogram": {str(k): v for k, v in sorted(self.people_histogram.items())},
            "people": self.people,
            "predicted": self.predicted,
            "events": dict(self.events),
            "joints_reconstructed": self.joints_reconstructed,
            "reprojection_median_px": self.reprojection_median_px,
            "reprojection_mean_px": _finite(self.mean_reprojection_px),
            "reprojection_confident_median_px": _finite(self.median_confident_reprojection_px),
            "reprojection_median_resolution_px": self.reprojection.bin_width / 2,
            "per_camera": {k: v.as_dict() for k, v in self.per_camera.items()},
            "sources": self.sources,
            "skipped_files": len(self.skipped_files),
            "two_way_frames": self.two_way_frames,
            "interrupted": self.interrupted,
            "error": self.error,
            "outputs": [str(p) for p in self.outputs],
            "failed_outputs": dict(self.failed_outputs),
            # only where detection was pipelined: a recorded run's summary.json is as before
            **({"pipeline": dict(self.pipeline)} if self.pipeline else {}),
            # only where detection ran in regions
            **({"regions": dict(self.regions)} if self.regions else {}),
            **({"detector": dict(self.detector)} if self.detector else {}),
            **({"light": dict(self.light)} if self.light else {}),
            **({"carry": dict(self.carry)} if self.carry else {}),
        }


def write_summary(path: str | Path, summary: RunSummary) -> Path:
    """summary.json; returns its path."""
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(summary.as_dict(), indent=1) + "\n", encoding="utf-8")
    except OSError as e:
        raise StereoposeError(f"{path}: cannot write the run summary: {e.strerror}") from None
    return path
