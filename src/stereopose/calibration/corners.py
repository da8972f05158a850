"""Robust checkerboard corner detection.

A plain OpenCV call often misses boards (motion blur, uneven light, a board filling the frame)
and, worse, sometimes returns a grid whose corners are not the board's. Here several detectors
and image preparations are tried in turn — OpenCV's sector-based detector at full and reduced
resolution, on the image as is, contrast-equalised and slightly blurred, then the classic
detector — and every candidate is checked: its corners must fit a plane-to-image homography
to within a fraction of a square, which rejects scrambled grids, and must not continue beyond
its border (part of a bigger board: the board size given is wrong). The accepted corners are
refined to sub-pixel accuracy and put in a canonical order (rows of `cols` corners, one
handedness, and on boards with an even number of squares along a side, the first corner next
to a dark square), so that corner k is the same physical corner in every photo (up to a half
turn of the board when both sides have an odd number of squares, as 15 x 11).
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import cv2
import numpy as np

from stereopose.calibration.board import Board

_SB_FLAGS = cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_ACCURACY
_CLASSIC_FLAGS = (
    cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_FILTER_QUADS
)
_SUBPIX = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-3)
CLASSIC_MAX_PX = 1100
MAX_FIT_FRACTION = 0.2  # of the mean square size: how far a corner may be off the homography


@dataclass(frozen=True)
class Corners:
    """Corners (cols * rows, 2) in pixels, canonical order; how they were found; the fit of a
    homography to them (largest error, pixels) and the mean square size in pixels."""

    points: np.ndarray
    method: str
    fit_px: float
    square_px: float


def to_gray(image: np.ndarray) -> np.ndarray:
    if image.ndim == 3:
        return cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    return image


def _candidates(gray: np.ndarray, board: Board) -> Iterator[tuple[str, np.ndarray]]:
    """(method, corners (N, 2) in full-resolution pixels) from each detector in turn.

    The classic detector runs only on images of at most CLASSIC_MAX_PX pixels on their long
    side: on large cluttered images it can take half a minute to find nothing."""
    long_side = max(gray.shape)
    scales = [1.0] + [s for s in (0.5, 0.35) if long_side * s >= 400]
    clahe = cv2.createCLAHE(2.0, (8, 8))
    for scale in scales:
        img = (
            gray
            if scale == 1.0
            else cv2.resize(gray, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
        )
        preps = (
            ("", img),
            ("equalised ", clahe.apply(img)),
            ("blurred ", cv2.GaussianBlur(img, (5, 5), 0)),
        )
        for prep, im in preps:
            ok, c = cv2.findChessboardCornersSB(im, board.size, flags=_SB_FLAGS)
            if ok:
                yield f"sector-based, {prep}x{scale:g}", c.reshape(-1, 2) / scale
        if max(img.shape) <= CLASSIC_MAX_PX:
            for prep, im in preps:
                ok, c = cv2.findChessboardCorners(im, board.size, None, _CLASSIC_FLAGS)
                if ok:
                    yield f"classic, {prep}x{scale:g}", c.reshape(-1, 2) / scale


def _grid_fit(points: np.ndarray, board: Board) -> tuple[float, float]:
    """Largest distance of the corners to the best homography of the board's grid, and the
    mean square size, in pixels."""
    grid = board.object_points()[:, :2] / board.square_m
    H, _ = cv2.findHomography(grid, points, 0)
    if H is None:
        return np.inf, 0.0
    fit = cv2.perspectiveTransform(grid.reshape(-1, 1, 2), H).reshape(-1, 2)
    g = points.reshape(board.rows, board.cols, 2)
    square = np.mean(
        np.concatenate(
            [
                np.linalg.norm(np.diff(g, axis=1), axis=-1).ravel(),
                np.linalg.norm(np.diff(g, axis=0), axis=-1).ravel(),
            ]
        )
    )
    return float(np.abs(fit - points).max()), float(square)


def canonical(points: np.ndarray, board: Board) -> np.ndarray:
    """Corners in rows of `cols`, ordered so that the row direction turned a quarter
    clockwise (in the image, y down) gives the column direction; the detector may hand them
    over transposed or mirrored."""
    p = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    a = p.reshape(board.rows, board.cols, 2)
    b = p.reshape(board.cols, board.rows, 2).transpose(1, 0, 2)

    def bend(g: np.ndarray) -> float:  # straightness of rows and columns
        return float(
            np.linalg.norm(g[:, 2:] - 2 * g[:, 1:-1] + g[:, :-2], axis=-1).sum()
            + np.linalg.norm(g[2:] - 2 * g[1:-1] + g[:-2], axis=-1).sum()
        )

    g = a if board.cols < 3 or board.rows < 3 or bend(a) <= bend(b) else b
    row, col = g[0, -1] - g[0, 0], g[-1, 0] - g[0, 0]
    if row[0] * col[1] - row[1] * col[0] < 0:
        g = g[:, ::-1]
    return np.ascontiguousarray(g.reshape(-1, 2))


def _inside_larger_board(gray: np.ndarray, pts: np.ndarray, board: Board) -> bool:
    """Whether the grid found continues beyond the board's own border: the squares two rows
    outside the inner corners alternate dark and light (a bigger board, read with the wrong
    size) instead of being the board's plain margin."""
    grid = board.object_points()[:, :2] / board.square_m
    H, _ = cv2.findHomography(grid, pts, 0)
    if H is None:
        return False
    h, w = gray.shape

    def sample(xy: np.ndarray) -> np.ndarray:
        uv = cv2.perspectiveTransform(xy.reshape(-1, 1, 2).astype(np.float64), H).reshape(-1, 2)
        ok = (uv[:, 0] >= 0) & (uv[:, 0] < w - 1) & (uv[:, 1] >= 0) & (uv[:, 1] < h - 1)
        out = np.full(len(uv), np.nan)
        out[ok] = gray[uv[ok, 1].round().astype(int), uv[ok, 0].round().astype(int)]
        return out

    # contrast of the board's own squares
    cx, cy = np.meshgrid(np.arange(board.cols - 1) + 0.5, np.arange(board.rows - 1) + 0.5)
    inner = sample(np.stack([cx.ravel(), cy.ravel()], -1))
    contrast = np.nanpercentile(inner, 90) - np.nanpercentile(inner, 10)
    if not contrast > 0:
        return False
    xs = np.arange(-1, board.cols) + 0.5
    ys = np.arange(-1, board.rows) + 0.5
    rings = [
        np.stack([xs, np.full_like(xs, -1.5)], -1),
        np.stack([xs, np.full_like(xs, board.rows + 0.5)], -1),
        np.stack([np.full_like(ys, -1.5), ys], -1),
        np.stack([np.full_like(ys, board.cols + 0.5), ys], -1),
    ]
    for ring in rings:
        v = sample(ring)
        steps = np.abs(np.diff(v))
        steps = steps[np.isfinite(steps)]
        if steps.size >= 3 and np.median(steps) > 0.5 * contrast:
            return True
    return False


def _dark_first(gray: np.ndarray, pts: np.ndarray, board: Board) -> np.ndarray:
    """On a board whose half turn swaps the colours at its corners (an even number of squares
    along one side), the order in which the square diagonally outside the first corner is the
    dark one; other boards are left as they are (their first corner is one of two)."""
    if board.cols % 2 == 0 and board.rows % 2 == 0:
        return pts  # odd x odd squares: the half-turned board looks the same
    grid = board.object_points()[:, :2] / board.square_m
    H, _ = cv2.findHomography(grid, pts, 0)
    if H is None:
        return pts
    probe = np.array([[-0.5, -0.5], [board.cols - 0.5, board.rows - 0.5]])
    uv = cv2.perspectiveTransform(probe.reshape(-1, 1, 2), H).reshape(-1, 2).round().astype(int)
    h, w = gray.shape
    if not ((uv >= 0).all() and (uv[:, 0] < w).all() and (uv[:, 1] < h).all()):
        return pts
    first, last = gray[uv[0, 1], uv[0, 0]], gray[uv[1, 1], uv[1, 0]]
    return pts[::-1].copy() if first > last else pts


def find_corners(image: np.ndarray, board: Board) -> Corners | None:
    """The board's corners in an image (gray or BGR), or None when no candidate passes."""
    gray = to_gray(image)
    for method, pts in _candidates(gray, board):
        pts = canonical(pts, board)
        fit, square = _grid_fit(pts, board)
        if not fit <= MAX_FIT_FRACTION * square or _inside_larger_board(gray, pts, board):
            continue
        half = int(np.clip(0.25 * square, 2, 11))
        refined = cv2.cornerSubPix(
            gray, pts.astype(np.float32).reshape(-1, 1, 2), (half, half), (-1, -1), _SUBPIX
        ).reshape(-1, 2)
        # keep the refinement only where it stayed near the detection
        moved = np.linalg.norm(refined - pts, axis=-1) > 0.5 * half
        pts = np.where(moved[:, None], pts, refined.astype(np.float64))
        fit, square = _grid_fit(pts, board)
        return Corners(_dark_first(gray, pts, board), method, fit, square)
    return None
