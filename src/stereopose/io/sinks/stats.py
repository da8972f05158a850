"""Statistics sinks: the run summary (summary.json) and the per-camera reprojection figures,
kept as running aggregates (io.aggregates), so their size is fixed however long a run lasts."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from stereopose.geometry.camera import project_to_rig
from stereopose.io.sinks.base import ClosesOnce, FrameResult
from stereopose.io.summary import CameraStats, RunSummary, write_summary
from stereopose.io.writing import probe_output
from stereopose.skeleton import NUM_JOINTS, SWAP
from stereopose.types import People2D, Rig


class SummarySink(ClosesOnce):
    """Adds each frame's people and events to `summary`; at close, writes it to `path`
    (summary.json; None: kept in memory only). The frame loop fills in the timings, the
    trajectories and the outputs before closing it, last but for the report. Its folder is
    tried at once."""

    stage = "write"

    def __init__(self, summary: RunSummary, path: str | Path | None = None) -> None:
        self.summary = summary
        self.path = Path(path) if path is not None else None
        if self.path is not None:
            probe_output(self.path, "the run summary")

    def write(self, frame: FrameResult) -> None:
        self.summary.add(frame.people3d, frame.events)

    def _close(self) -> list[Path]:
        return [] if self.path is None else [write_summary(self.path, self.summary)]


def _medians(d: np.ndarray, ok: np.ndarray) -> np.ndarray:
    """(S,) median of each row of d (S, J) over its `ok` entries; inf for a row with none."""
    n = ok.sum(axis=1)
    s = np.sort(np.where(ok, d, np.inf), axis=1)
    rows = np.arange(len(d))
    return 0.5 * (s[rows, np.maximum(n - 1, 0) // 2] + s[rows, n // 2])


def reprojection_errors(
    px: np.ndarray, conf: np.ndarray, detections: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Pixel distances between people's 3D joints projected into the cameras and the
    detections they were reconstructed from, over the joints with conf > 0.5 in both.

    px: (S, 17, 2) the joints in pixels (NaN: not projected); conf: (S, 17) their confidence;
    detections: (S, 17, 3) x, y, conf in pixels (NaN: no detection). A detection whose
    left/right labels the reconstruction found swapped is compared swapped back: per row, of
    the two orders the one with the lower median distance. Returns the chosen distances (S, 17)
    and where they count (S, 17).
    """
    orders = []
    for order in (slice(None), SWAP):
        kp = detections[:, order]
        ok = (kp[..., 2] > 0.5) & (conf > 0.5) & np.isfinite(px[..., 0])
        d = np.hypot(px[..., 0] - kp[..., 0], px[..., 1] - kp[..., 1])
        orders.append((d, ok, _medians(d, ok)))
    (d, ok, m), (ds, oks, ms) = orders
    swapped = (ms < m)[:, None]
    return np.where(swapped, ds, d), np.where(swapped, oks, ok)


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
        p3 = frame.people3d
        P, C = len(p3), len(self.rig)
        kp = np.full((P, C, NUM_JOINTS, 3), np.nan)
        seen = np.zeros(C, dtype=bool)
        for ci, name in enumerate(self.rig.names):
            p2: People2D | None = frame.people2d.get(name)
            if p2 is None:
                continue
            seen[ci] = True
            st = self.stats[name]
            st.frames += 1
            st.detections += len(p2)
            sel = np.flatnonzero(p3.detections[:, ci] >= 0)
            if sel.size:
                kp[sel, ci] = p2.keypoints[p3.detections[sel, ci]]
        members = (p3.detections >= 0) & seen  # (P, C)
        if not members.any():
            return
        px = project_to_rig(p3.joints, self.rig).transpose(0, 2, 1, 3)  # (P, C, 17, 2)
        p, c = np.nonzero(members)
        d, ok = reprojection_errors(px[p, c], p3.conf[p], kp[p, c])
        for ci in np.unique(c).tolist():
            rows = c == ci
            self.stats[self.rig.names[ci]].reprojection.add(d[rows][ok[rows]])

    def close(self) -> list[Path]:
        return []
