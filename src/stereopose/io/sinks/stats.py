"""Statistics sinks: the run summary (summary.json) and the per-camera reprojection figures,
kept as running aggregates (io.aggregates), so their size is fixed however long a run lasts."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from stereopose.geometry.camera import project
from stereopose.io.sinks.base import FrameResult
from stereopose.io.summary import CameraStats, RunSummary, write_summary
from stereopose.skeleton import SWAP
from stereopose.types import People2D, People3D, Rig


class SummarySink:
    """Adds each frame's people and events to `summary`; at close, writes it to `path`
    (summary.json; None: kept in memory only). The frame loop fills in the timings, the
    trajectories and the outputs before closing it, last but for the report."""

    stage = "write"

    def __init__(self, summary: RunSummary, path: str | Path | None = None) -> None:
        self.summary = summary
        self.path = Path(path) if path is not None else None
        self._closed = False

    def write(self, frame: FrameResult) -> None:
        self.summary.add(frame.people3d, frame.events)

    def close(self) -> list[Path]:
        if self._closed or self.path is None:
            return []
        self._closed = True
        self.summary.outputs.append(self.path)
        return [write_summary(self.path, self.summary)]


def reprojection_errors(camera, people3d: People3D, p: int, detection: np.ndarray) -> np.ndarray:
    """Pixel distances between person `p`'s 3D joints projected into `camera` and the
    detection (17, 3) they were reconstructed from, over the joints with conf > 0.5 in both. A
    detection whose left/right labels the reconstruction found swapped is compared swapped
    back: of the two orders, the one with the lower median distance."""
    px = project(people3d.joints[p], camera)
    best: np.ndarray | None = None
    for order in (slice(None), SWAP):
        kp = detection[order]
        ok = (kp[:, 2] > 0.5) & (people3d.conf[p] > 0.5) & np.isfinite(px[:, 0])
        d = np.linalg.norm(px[ok] - kp[ok, :2], axis=1)
        if len(d) and (best is None or np.median(d) < np.median(best)):
            best = d
    return best if best is not None else np.zeros(0)


class CameraStatsSink:
    """Per camera: frames, detections, and the reprojection error of the output joints against
    the detections they rest on, into `stats` (camera name -> CameraStats)."""

    stage = "write"

    def __init__(self, rig: Rig, stats: dict[str, CameraStats]) -> None:
        self.rig = rig
        self.stats = stats
        for name in rig.names:
            stats.setdefault(name, CameraStats())

    def write(self, frame: FrameResult) -> None:
        people3d = frame.people3d
        for ci, cam in enumerate(self.rig):
            p2: People2D | None = frame.people2d.get(cam.name)
            if p2 is None:
                continue
            st = self.stats[cam.name]
            st.frames += 1
            st.detections += len(p2)
            for p in np.flatnonzero(people3d.detections[:, ci] >= 0):
                det = p2.keypoints[people3d.detections[p, ci]]
                st.reprojection.add(reprojection_errors(cam, people3d, p, det))

    def close(self) -> list[Path]:
        return []
