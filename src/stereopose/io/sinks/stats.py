"""Statistics sinks: the run summary (summary.json) and the per-camera reprojection figures,
kept as running aggregates (io.aggregates), so their size is fixed however long a run lasts."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from stereopose.geometry.camera import project
from stereopose.io.sinks.base import FrameResult
from stereopose.io.summary import CameraStats, RunSummary, write_summary
from stereopose.skeleton import SWAP
from stereopose.types import People2D, Rig


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
        return [write_summary(self.path, self.summary)]


def _medians(d: np.ndarray, ok: np.ndarray) -> np.ndarray:
    """(S,) median of each row of d (S, J) over its `ok` entries; inf for a row with none."""
    n = ok.sum(axis=1)
    s = np.sort(np.where(ok, d, np.inf), axis=1)
    rows = np.arange(len(d))
    return 0.5 * (s[rows, np.maximum(n - 1, 0) // 2] + s[rows, n // 2])


def reprojection_errors(camera, joints: np.ndarray, conf: np.ndarray, detections: np.ndarray):
    """Pixel distances between people's 3D joints projected into `camera` and the detections
    they were reconstructed from, over the joints with conf > 0.5 in both.

    joints: (S, 17, 3) metres; conf: (S, 17); detections: (S, 17, 3) x, y, conf in pixels. A
    detection whose left/right labels the reconstruction found swapped is compared swapped
    back: per person, of the two orders the one with the lower median distance. Returns the
    chosen distances of every person, flat.
    """
    px = project(joints, camera)
    orders = []
    for order in (slice(None), SWAP):
        kp = detections[:, order]
        ok = (kp[..., 2] > 0.5) & (conf > 0.5) & np.isfinite(px[..., 0])
        d = np.linalg.norm(px - kp[..., :2], axis=-1)
        orders.append((d, ok, _medians(d, ok)))
    (d, ok, m), (ds, oks, ms) = orders
    swapped = (ms < m)[:, None]
    return np.where(swapped, ds, d)[np.where(swapped, oks, ok)]


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
            sel = np.flatnonzero(people3d.detections[:, ci] >= 0)
            if sel.size:
                det = p2.keypoints[people3d.detections[sel, ci]]
                errors = reprojection_errors(cam, people3d.joints[sel], people3d.conf[sel], det)
                st.reprojection.add(errors)

    def close(self) -> list[Path]:
        return []
