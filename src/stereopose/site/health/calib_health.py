"""The calibration's health: a camera knocked out of place shows as a rising reprojection error.

    health = CalibrationHealth(rig, warn_factor=config.serve.calib_warn_factor)
    events = health.update(frame)         # each FrameResult of the frame loop

Per camera and frame, one sample: the 3D joints of the people seen by at least three cameras
projected into the camera against the camera's own 2D detections, per person the detection that
fits best (median joint distance, in pixels, left/right as fits best; capped at a tenth of the
image diagonal), the median over the people. The detection need not be one the
3D rests on: a camera that moved is outvoted by the others, and its detections then no longer
match the people's projections. The first `baseline_samples` samples give the camera's baseline
(their median); the running value is the median of the last `window` samples. When it exceeds
warn_factor times the baseline (the baseline taken as at least floor_px), a `calibration_drift`
event is raised once; a `calibration_recovered` event when it falls back below half way between
the baseline and that threshold. Memory: a bounded window per camera.
"""

from __future__ import annotations

import logging
import math
from collections import deque
from collections.abc import Mapping

import numpy as np

from stereopose.geometry.camera import project_to_rig
from stereopose.io.sinks.base import FrameResult
from stereopose.io.sinks.stats import reprojection_errors
from stereopose.site.health.watch import camera_event
from stereopose.types import Event, People2D, People3D, Rig

__all__ = ["CalibrationHealth", "camera_errors"]

logger = logging.getLogger(__name__)

MIN_JOINTS = 6  # joints a person/detection pair must share for its distance to count
MIN_VIEWS = 3  # cameras a person's joints must rest on to test another camera
CAP_OF_DIAGONAL = 0.1  # a person's error is capped at this fraction of the image diagonal


def _person_errors(px: np.ndarray, conf: np.ndarray, kp: np.ndarray) -> np.ndarray:
    """(P,) per person the median joint distance to the best-fitting detection (inf: none).

    px: (P, 17, 2) the people projected; conf: (P, 17); kp: (D, 17, 3) the detections."""
    P, D = len(px), len(kp)
    if P == 0 or D == 0:
        return np.full(P, np.inf)
    pxs = np.repeat(px, D, axis=0)  # (P*D, 17, 2): each person against each detection
    confs = np.repeat(conf, D, axis=0)
    kps = np.tile(kp, (P, 1, 1))
    d, ok = reprojection_errors(pxs, confs, kps)
    n = ok.sum(-1)
    med = np.array(
        [
            np.median(row[m]) if k >= MIN_JOINTS else np.inf
            for row, m, k in zip(d, ok, n, strict=True)
        ]
    )
    return med.reshape(P, D).min(axis=1)


def camera_errors(
    people3d: People3D, people2d: Mapping[str, People2D], rig: Rig
) -> dict[str, float]:
    """Camera name -> the frame's reprojection sample (pixels) for the cameras with both
    detections and a 3D person that fits one (see the module's docstring)."""
    # a person seen by two cameras fits them whatever their calibration: only people seen by
    # MIN_VIEWS or more say anything about one camera
    keep = people3d.views.max(axis=1, initial=0) >= MIN_VIEWS
    if not keep.any():
        return {}
    joints, conf = people3d.joints[keep], people3d.conf[keep]
    px = project_to_rig(joints, rig)  # (P, 17, C, 2)
    out = {}
    for ci, cam in enumerate(rig):
        p2 = people2d.get(cam.name)
        if p2 is None or len(p2) == 0:
            continue
        errs = _person_errors(px[:, :, ci], conf, np.asarray(p2.keypoints))
        # beyond the cap the person is taken as not seen by this camera (occluded, out of
        # view): counted at the cap, so that one such person moves the median little
        errs = np.minimum(errs, CAP_OF_DIAGONAL * float(np.hypot(*cam.size)))
        out[cam.name] = float(np.median(errs))
    return out


class _Camera:
    """One camera's samples: the baseline (while forming, its samples) and the window."""

    def __init__(self, baseline_samples: int, window: int) -> None:
        self.first: list[float] = []
        self.baseline: float | None = None
        self.recent: deque[float] = deque(maxlen=window)
        self.baseline_samples = baseline_samples
        self.drifting = False

    def add(self, value: float) -> None:
        if self.baseline is None:
            self.first.append(value)
            if len(self.first) >= self.baseline_samples:
                self.baseline = float(np.median(self.first))
                self.first = []
        self.recent.append(value)

    @property
    def running(self) -> float | None:
        return float(np.median(self.recent)) if self.recent else None


class CalibrationHealth:
    """Per camera a baseline and a running reprojection error; events when they part."""

    def __init__(
        self,
        rig: Rig,
        warn_factor: float = 2.0,
        *,
        baseline_samples: int = 300,
        window: int = 150,
        floor_px: float = 1.0,
    ) -> None:
        """rig: the calibration the 3D people are made with; warn_factor (> 1): the rise that
        warns; baseline_samples, window: samples (one per camera per frame with people);
        floor_px: the least baseline a threshold is taken from (a near-perfect baseline would
        warn on noise)."""
        if not (warn_factor > 1 and math.isfinite(warn_factor)):
            raise ValueError(f"warn_factor must be a number above 1, got {warn_factor}")
        if baseline_samples < 1 or window < 1:
            raise ValueError(
                f"baseline_samples and window must be at least 1, got {baseline_samples}, {window}"
            )
        self.rig = rig
        self.warn_factor = float(warn_factor)
        self.floor_px = float(floor_px)
        self.window = window
        self.cameras = {n: _Camera(baseline_samples, window) for n in rig.names}

    def update(self, frame: FrameResult) -> list[Event]:
        """The frame's samples added; the calibration events they raise."""
        out = []
        for name, value in camera_errors(frame.people3d, frame.people2d, self.rig).items():
            out.extend(self.add(name, value, frame.t, frame.frame))
        return out

    def add(self, name: str, error_px: float, t: float, frame: int) -> list[Event]:
        """One sample of camera `name` at time t, frame; the event it raises, if any."""
        cam = self.cameras[name]
        cam.add(float(error_px))
        base, running = cam.baseline, cam.running
        if base is None or running is None or len(cam.recent) < self.window:
            return []
        threshold = self.warn_factor * max(base, self.floor_px)
        if not cam.drifting and running > threshold:
            cam.drifting = True
            logger.error(
                "camera %s: reprojection error %.1f px against its baseline %.1f px: moved or "
                "knocked out of place?",
                name,
                running,
                base,
            )
            return [_drift_event("calibration_drift", name, t, frame, running, base)]
        if cam.drifting and running < 0.5 * (base + threshold):
            cam.drifting = False
            logger.warning("camera %s: reprojection error back to %.1f px", name, running)
            return [_drift_event("calibration_recovered", name, t, frame, running, base)]
        return []

    def set_camera(self, rig: Rig, name: str) -> None:
        """The rig with camera `name` placed again: its running window starts afresh (its
        baseline kept), so `calibration_recovered` follows once its error is back."""
        self.rig = rig
        self.cameras[name].recent.clear()

    def figures(self) -> dict[str, dict[str, float | bool | None]]:
        """Per camera its baseline and running error (pixels) and whether it drifts (health)."""
        return {
            n: {"baseline_px": c.baseline, "running_px": c.running, "drifting": c.drifting}
            for n, c in self.cameras.items()
        }


def _drift_event(type_: str, name: str, t: float, frame: int, running: float, base: float) -> Event:
    """A camera's drift or recovery: its running error against its baseline, pixels."""
    return camera_event(type_, name, t, frame, t, reprojection_px=running, baseline_px=base)
