"""Per-camera overlay videos: the detector's 2D skeletons, and the 3D people reprojected with
their ids, drawn over the camera's frames.

The detections are thin white lines; each tracked person's 3D joints, projected through the
camera's calibration (lens distortion included), are drawn in the person's colour with
``id N`` above the head, dimmed when the pose is predicted (a bridged gap). The gap between the
two shows the reprojection error at a glance.
"""

from __future__ import annotations

import logging
from pathlib import Path

import cv2
import numpy as np

from stereopose.errors import StereoposeError
from stereopose.geometry.camera import project
from stereopose.io.mp4 import FrameWriter
from stereopose.skeleton import LIMBS
from stereopose.types import Camera, People2D, People3D
from stereopose.viz.colours import id_colour_bgr

logger = logging.getLogger(__name__)


def colour(person_id: int) -> tuple[int, int, int]:
    """The person's colour (viz.colours: the same on the console's plan and 3D view), BGR."""
    return id_colour_bgr(person_id)


def _pt(xy: np.ndarray, scale: float) -> tuple[int, int]:
    return round(float(xy[0]) * scale), round(float(xy[1]) * scale)


def draw_overlay(
    image: np.ndarray,
    camera: Camera,
    people2d: People2D | None,
    people3d: People3D,
    scale: float = 1.0,
    label: str = "",
    min_conf: float = 0.3,
) -> np.ndarray:
    """A copy of ``image`` (resized by ``scale``) with detections and reprojected 3D people.

    Points are in the calibration's pixels: an image of another size (a camera's detection
    substream) is resized to ``scale`` times the calibration's size, as a full one would be."""
    cw, ch = (round(v) for v in camera.size)
    h, w = image.shape[:2]
    if (w, h) != (cw, ch):
        w, h = cw, ch
        out = cv2.resize(image, (max(1, round(w * scale)), max(1, round(h * scale))))
    elif scale != 1.0:
        out = cv2.resize(image, (round(w * scale), round(h * scale)))
    else:
        out = image.copy()
    thick = max(1, round(3 * scale))
    if people2d is not None:
        for kp in people2d.keypoints:
            ok = np.isfinite(kp[:, 0]) & (kp[:, 2] >= min_conf)
            for a, b in LIMBS:
                if ok[a] and ok[b]:
                    cv2.line(
                        out, _pt(kp[a], scale), _pt(kp[b], scale), (255, 255, 255), 1, cv2.LINE_AA
                    )
    if len(people3d):
        px = project(people3d.joints, camera)  # (P, 17, 2)
        for p in range(len(people3d)):
            pid = int(people3d.ids[p])
            c = colour(pid)
            if people3d.predicted is not None and people3d.predicted[p]:
                c = tuple(int(v * 0.5) for v in c)
            ok = np.isfinite(px[p]).all(axis=1)
            inside = ok & (px[p, :, 0] > -w) & (px[p, :, 0] < 2 * w)
            inside &= (px[p, :, 1] > -h) & (px[p, :, 1] < 2 * h)
            if not inside.any():
                continue
            for a, b in LIMBS:
                if inside[a] and inside[b]:
                    cv2.line(out, _pt(px[p, a], scale), _pt(px[p, b], scale), c, thick, cv2.LINE_AA)
            for j in np.flatnonzero(inside):
                cv2.circle(out, _pt(px[p, j], scale), thick + 1, c, -1, cv2.LINE_AA)
            top = px[p, inside][np.argmin(px[p, inside, 1])]
            x, y = _pt(top, scale)
            text = f"id {pid}"
            fs = max(0.4, 1.2 * scale)
            (tw, th), _ = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, fs, 2)
            y = max(th + 4, y - 12)
            cv2.rectangle(out, (x - tw // 2 - 3, y - th - 4), (x + tw // 2 + 3, y + 4), c, -1)
            cv2.putText(
                out,
                text,
                (x - tw // 2, y),
                cv2.FONT_HERSHEY_SIMPLEX,
                fs,
                (255, 255, 255),
                2,
                cv2.LINE_AA,
            )
    if label:
        fs = max(0.4, 1.0 * scale)
        cv2.putText(
            out,
            label,
            (8, int(30 * max(scale, 0.5))),
            cv2.FONT_HERSHEY_SIMPLEX,
            fs,
            (0, 0, 0),
            4,
            cv2.LINE_AA,
        )
        cv2.putText(
            out,
            label,
            (8, int(30 * max(scale, 0.5))),
            cv2.FONT_HERSHEY_SIMPLEX,
            fs,
            (255, 255, 255),
            1,
            cv2.LINE_AA,
        )
    return out


class OverlayVideo:
    """One camera's overlay MP4, opened on its first frame (its size is known then)."""

    def __init__(self, path: str | Path, camera: Camera, fps: float, scale: float = 0.5) -> None:
        if not 0 < scale <= 1:
            raise StereoposeError(f"overlay scale must be in (0, 1], got {scale}")
        self.path = Path(path)
        self.camera, self.fps, self.scale = camera, fps, scale
        self._video = FrameWriter(self.path, fps, "the overlay video")

    @property
    def frames(self) -> int:
        return self._video.frames

    @property
    def size(self) -> tuple[int, int] | None:
        return self._video.size

    def write(
        self, image: np.ndarray, people2d: People2D | None, people3d: People3D, label: str = ""
    ) -> None:
        out = draw_overlay(image, self.camera, people2d, people3d, self.scale, label)
        if not self._video.opened:
            self.path.parent.mkdir(parents=True, exist_ok=True)
        self._video.write(out)

    def close(self) -> Path | None:
        if not self._video.opened:
            return None
        self._video.close()
        return self.path
