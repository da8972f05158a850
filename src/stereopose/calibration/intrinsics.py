"""Intrinsics of one camera from checkerboard photos (Zhang's method), and the photos behind.

Photos (or frames sampled from a video) are read and searched for the board; a photo without
one, or unreadable, is reported and skipped. Zhang's method (OpenCV) estimates fx, fy, cx, cy
and k1 k2 p1 p2 (k3 on request); photos whose own reprojection error stands out are dropped one
at a time, worst first, and the camera is estimated again.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from stereopose.calibration.board import Board
from stereopose.calibration.corners import Corners, find_corners
from stereopose.errors import CalibrationError
from stereopose.types import Camera

logger = logging.getLogger(__name__)

IMAGE_SUFFIXES = {".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff"}
VIDEO_SUFFIXES = {".mp4", ".avi", ".mov", ".mkv", ".m4v", ".webm"}
MIN_VIEWS = 3


@dataclass
class Detection:
    """The board found (or not) in one photo."""

    name: str
    image_size: tuple[int, int] | None
    corners: Corners | None = None
    problem: str | None = None  # why no corners: unreadable, no board


@dataclass
class IntrinsicsResult:
    camera: Camera
    rms_px: float
    view_rms_px: dict[str, float]
    used: list[str]
    rejected: dict[str, str] = field(default_factory=dict)  # photo -> why
    coverage: float = 0.0  # fraction of a 10 x 10 grid over the image holding a corner
    warnings: list[str] = field(default_factory=list)


def camera_name(folder: str) -> str:
    """Camera name from a folder: `int_cam01_img` -> `cam01` (known prefixes and suffixes
    removed)."""
    name = folder
    for prefix in ("int_", "ext_", "intrinsics_", "extrinsics_"):
        if name.lower().startswith(prefix):
            name = name[len(prefix) :]
    for suffix in ("_img", "_images", "_imgs", "_int", "_ext"):
        if name.lower().endswith(suffix):
            name = name[: -len(suffix)]
    return name or folder


def iter_images(path: Path, every_s: float = 0.5) -> Iterator[tuple[str, np.ndarray | None]]:
    """(name, image or None if unreadable) of the photos in a folder, sorted by name, or of
    frames sampled every `every_s` seconds from a video file."""
    if path.is_file() and path.suffix.lower() in VIDEO_SUFFIXES:
        cap = cv2.VideoCapture(str(path))
        if not cap.isOpened():
            raise CalibrationError(f"{path}: cannot open the video")
        fps = cap.get(cv2.CAP_PROP_FPS) or 25.0
        step = max(1, round(every_s * fps))
        k = got = 0
        while True:
            ok, frame = cap.read()
            if not ok:
                break
            if k % step == 0:
                got += 1
                yield f"{path.stem}_{k:06d}", frame
            k += 1
        cap.release()
        if got == 0:
            raise CalibrationError(f"{path}: no frame could be read from the video")
        return
    if not path.is_dir():
        raise CalibrationError(f"{path}: not a folder of photos or a video file")
    files = sorted(p for p in path.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
    if not files:
        raise CalibrationError(f"{path}: no photos (*.jpg, *.png, ...) in the folder")
    for f in files:
        yield f.name, cv2.imread(str(f))


def detect_all(images: Iterable[tuple[str, np.ndarray | None]], board: Board) -> list[Detection]:
    out = []
    for name, img in images:
        if img is None:
            out.append(Detection(name, None, problem="unreadable image"))
            logger.warning("%s: unreadable image, skipped", name)
            continue
        size = (int(img.shape[1]), int(img.shape[0]))
        c = find_corners(img, board)
        if c is None:
            out.append(Detection(name, size, problem=f"no {board.cols}x{board.rows} board found"))
            logger.info("%s: no board found", name)
        else:
            out.append(Detection(name, size, c))
    return out


def coverage(points: Iterable[np.ndarray], size: tuple[int, int], cells: int = 10) -> float:
    """Fraction of a cells x cells grid over the image that holds at least one corner."""
    hit = np.zeros((cells, cells), dtype=bool)
    for p in points:
        ij = np.clip((p / np.array(size) * cells).astype(int), 0, cells - 1)
        hit[ij[:, 1], ij[:, 0]] = True
    return float(hit.mean())


def _calibrate(
    obj: np.ndarray,
    pts: list[np.ndarray],
    size: tuple[int, int],
    k3: bool,
    K0: np.ndarray | None = None,
    dist0: np.ndarray | None = None,
) -> tuple[float, np.ndarray, np.ndarray, list[float], Sequence[np.ndarray], Sequence[np.ndarray]]:
    flags = 0 if k3 else cv2.CALIB_FIX_K3
    if K0 is not None:
        flags |= cv2.CALIB_USE_INTRINSIC_GUESS
    rms, K, dist, rvecs, tvecs = cv2.calibrateCamera(
        [obj] * len(pts), pts, size, K0, dist0, flags=flags
    )
    per_view = []
    for p, r, t in zip(pts, rvecs, tvecs, strict=True):
        proj, _ = cv2.projectPoints(obj, r, t, K, dist)
        per_view.append(float(np.sqrt(np.mean(np.sum((proj.reshape(-1, 2) - p) ** 2, -1)))))
    return float(rms), K, dist.ravel(), per_view, rvecs, tvecs


def calibrate_intrinsics(
    name: str,
    detections: list[Detection],
    board: Board,
    k3: bool = False,
    max_view_rms_px: float = 1.0,
    outlier_factor: float = 3.0,
) -> IntrinsicsResult:
    """One camera's intrinsics from its detections.

    A photo is rejected while its RMS exceeds max_view_rms_px and outlier_factor times the
    median of the others, worst first, keeping at least MIN_VIEWS photos.
    """
    good = [d for d in detections if d.corners is not None]
    sizes = {d.image_size for d in detections if d.image_size}
    if len(sizes) > 1:
        raise CalibrationError(f"camera {name}: photos of different sizes {sorted(sizes)}")
    if len(good) < MIN_VIEWS:
        found = ", ".join(d.name for d in good) or "none"
        raise CalibrationError(
            f"camera {name}: the {board.cols}x{board.rows} board was found in {len(good)} of "
            f"{len(detections)} photo(s) ({found}); at least {MIN_VIEWS} are needed. Check "
            "the board size (inner corners, e.g. 14x10 for 15 x 11 squares)"
        )
    size = sizes.pop()
    obj = board.object_points().astype(np.float32)
    rejected = {d.name: d.problem or "" for d in detections if d.corners is None}
    while True:
        pts = [c.points.astype(np.float32) for d in good if (c := d.corners) is not None]
        rms, K, dist, per_view, _, _ = _calibrate(obj, pts, size, k3)
        worst = int(np.argmax(per_view))
        others = np.median([v for i, v in enumerate(per_view) if i != worst])
        if (
            len(good) > MIN_VIEWS
            and per_view[worst] > max_view_rms_px
            and per_view[worst] > outlier_factor * others
        ):
            rejected[good[worst].name] = f"reprojection error {per_view[worst]:.2f} px"
            logger.info("%s: %s rejected (%.2f px)", name, good[worst].name, per_view[worst])
            del good[worst]
            continue
        break
    cam = Camera(
        name,
        (float(size[0]), float(size[1])),
        K,
        dist[:5] if k3 else dist[:4],
        np.zeros(3),
        np.zeros(3),
    )
    cov = coverage([c.points for d in good if (c := d.corners) is not None], size)
    result = IntrinsicsResult(
        cam,
        rms,
        {d.name: v for d, v in zip(good, per_view, strict=True)},
        [d.name for d in good],
        rejected,
        cov,
    )
    if cov < 0.3:
        result.warnings.append(
            f"camera {name}: corners cover only {100 * cov:.0f}% of the image; show the board "
            "near the edges and corners too, or distortion will be poorly estimated"
        )
    if rms > 1.0:
        result.warnings.append(f"camera {name}: high reprojection error ({rms:.2f} px)")
    if len(good) < 6:
        result.warnings.append(f"camera {name}: only {len(good)} usable photos (10-20 advised)")
    return result
