"""One sparse bundle adjustment of camera poses and 3D points, with a robust loss: the
finishing step of the rig from surveyed points, from people and of a camera's refinement.

Cameras keep their intrinsics (fx, fy, cx, cy, k1, k2, p1, p2: OpenCV's model); their poses
(Rodrigues vector and translation, world -> camera) and the points move, except those held.
Optional terms: a surveyed point pulled towards its surveyed position (`prior`, metres, with
its standard deviation), a person's bone held at one length over time (`bones`: the two
points of each observed bone and the index of its length, itself a parameter), and the
distance between two camera centres held (`baseline`: the scale of a rig from people).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from scipy.optimize import least_squares
from scipy.sparse import coo_matrix

from stereopose.calibration.extrinsics import rodrigues

if TYPE_CHECKING:
    from scipy.sparse import csr_array

__all__ = ["Bundle", "Solution", "adjust", "project_px"]


def project_px(pose: np.ndarray, intr: np.ndarray, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pixels of the distorted image and depths.

    pose: (N, 6) world -> camera per point; intr: (N, 8); X: (N, 3) world metres.
    Returns (N, 2) pixels and (N,) depths along the optical axis (metres)."""
    R = rodrigues(pose[:, :3])
    Xc = np.einsum("nij,nj->ni", R, X) + pose[:, 3:]
    z = Xc[:, 2]
    zs = np.where(np.abs(z) < 1e-9, 1e-9, z)
    x, y = Xc[:, 0] / zs, Xc[:, 1] / zs
    fx, fy, cx, cy, k1, k2, p1, p2 = intr.T
    r2 = x * x + y * y
    radial = 1 + r2 * (k1 + r2 * k2)
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    return np.stack([fx * xd + cx, fy * yd + cy], axis=1), z


@dataclass
class Bundle:
    """The problem. poses (C, 6), intr (C, 8), points (M, 3); observations: cam (N,), point
    (N,), uv (N, 2) pixels, weight (N,). free_cams (C,) and free_points (M,) say what moves.
    prior: (M, 3) surveyed positions (NaN: none) with prior_sigma_m. bones: (B, 3) point a,
    point b, length index; lengths (L,) their starting values, bone_sigma_m. baseline: (camera
    a, camera b, metres)."""

    poses: np.ndarray
    intr: np.ndarray
    points: np.ndarray
    cam: np.ndarray
    point: np.ndarray
    uv: np.ndarray
    weight: np.ndarray
    free_cams: np.ndarray
    free_points: np.ndarray
    prior: np.ndarray | None = None
    prior_sigma_m: float = 0.01
    bones: np.ndarray | None = None
    lengths: np.ndarray | None = None
    bone_sigma_m: float = 0.01
    baseline: tuple[int, int, float] | None = None


@dataclass
class Solution:
    poses: np.ndarray  # (C, 6)
    points: np.ndarray  # (M, 3)
    lengths: np.ndarray | None  # (L,) bone lengths
    residual_px: np.ndarray  # (N,) each observation's reprojection error
    cost: float


def _layout(b: Bundle) -> tuple[np.ndarray, np.ndarray, int]:
    """Column of each free camera's first parameter (-1: held), of each free point's, and the
    number of parameters before the bone lengths."""
    cam_col = np.full(len(b.poses), -1)
    cam_col[b.free_cams] = 6 * np.arange(int(b.free_cams.sum()))
    off = 6 * int(b.free_cams.sum())
    pt_col = np.full(len(b.points), -1)
    pt_col[b.free_points] = off + 3 * np.arange(int(b.free_points.sum()))
    return cam_col, pt_col, off + 3 * int(b.free_points.sum())


def _sparsity(
    b: Bundle, cam_col: np.ndarray, pt_col: np.ndarray, n_before_len: int, n_rows: list[int]
) -> csr_array:
    """Which parameters each residual depends on."""
    rows, cols = [], []
    N = len(b.cam)
    for d in range(2):
        r = 2 * np.arange(N) + d
        c = cam_col[b.cam]
        ok = c >= 0
        for j in range(6):
            rows.append(r[ok])
            cols.append(c[ok] + j)
        p = pt_col[b.point]
        ok = p >= 0
        for j in range(3):
            rows.append(r[ok])
            cols.append(p[ok] + j)
    row = 2 * N
    if b.prior is not None:
        has = np.flatnonzero(np.isfinite(b.prior[:, 0]) & (pt_col >= 0))
        for j in range(3):
            rows.append(row + 3 * np.arange(len(has)) + j)
            cols.append(pt_col[has] + j)
        row += 3 * len(has)
    if b.bones is not None and len(b.bones):
        r = row + np.arange(len(b.bones))
        for end in (0, 1):
            p = pt_col[b.bones[:, end]]
            ok = p >= 0
            for j in range(3):
                rows.append(r[ok])
                cols.append(p[ok] + j)
        rows.append(r)
        cols.append(n_before_len + b.bones[:, 2])
        row += len(b.bones)
    if b.baseline is not None:
        for k in b.baseline[:2]:
            if cam_col[k] >= 0:
                rows.append(np.full(6, row))
                cols.append(cam_col[k] + np.arange(6))
        row += 1
    n_rows.append(row)
    n_cols = n_before_len + (len(b.lengths) if b.lengths is not None else 0)
    rr, cc = np.concatenate(rows), np.concatenate(cols)
    return coo_matrix((np.ones(rr.size, dtype=np.int8), (rr, cc)), shape=(row, n_cols)).tocsr()


def adjust(
    b: Bundle, *, f_scale_px: float = 2.0, loss: str = "soft_l1", max_nfev: int = 60
) -> Solution:
    """Minimise the observations' weighted reprojection errors (pixels, robust `loss` beyond
    `f_scale_px`) with the prior, bone and baseline terms."""
    cam_col, pt_col, n_before_len = _layout(b)
    fc, fp = np.flatnonzero(b.free_cams), np.flatnonzero(b.free_points)
    has_prior = (
        np.flatnonzero(np.isfinite(b.prior[:, 0]) & b.free_points)
        if b.prior is not None
        else np.zeros(0, dtype=int)
    )
    w = np.sqrt(np.asarray(b.weight, dtype=np.float64))[:, None]

    def unpack(x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        poses, pts = b.poses.copy(), b.points.copy()
        poses[fc] = x[: 6 * len(fc)].reshape(-1, 6)
        pts[fp] = x[6 * len(fc) : n_before_len].reshape(-1, 3)
        lengths = x[n_before_len:] if b.lengths is not None else None
        return poses, pts, lengths

    def residuals(x: np.ndarray) -> np.ndarray:
        poses, pts, lengths = unpack(x)
        uv, _ = project_px(poses[b.cam], b.intr[b.cam], pts[b.point])
        out = [((uv - b.uv) * w).ravel()]
        if len(has_prior) and b.prior is not None:
            out.append(((pts[has_prior] - b.prior[has_prior]) / b.prior_sigma_m).ravel())
        if b.bones is not None and len(b.bones) and lengths is not None:
            d = np.linalg.norm(pts[b.bones[:, 0]] - pts[b.bones[:, 1]], axis=1)
            out.append((d - lengths[b.bones[:, 2]]) / b.bone_sigma_m)
        if b.baseline is not None:
            i, j, metres = b.baseline
            ci = -rodrigues(poses[i : i + 1, :3])[0].T @ poses[i, 3:]
            cj = -rodrigues(poses[j : j + 1, :3])[0].T @ poses[j, 3:]
            out.append(np.array([(np.linalg.norm(ci - cj) - metres) * 1e4]))
        return np.concatenate(out)

    x0 = [b.poses[fc].ravel(), b.points[fp].ravel()]
    if b.lengths is not None:
        x0.append(np.asarray(b.lengths, dtype=np.float64))
    x0 = np.concatenate(x0)
    S = _sparsity(b, cam_col, pt_col, n_before_len, [])
    sol = least_squares(
        residuals,
        x0,
        jac_sparsity=S,
        method="trf",
        tr_solver="lsmr",
        loss=loss,
        f_scale=f_scale_px,
        x_scale="jac",
        max_nfev=max_nfev,
    )
    poses, pts, lengths = unpack(sol.x)
    uv, _ = project_px(poses[b.cam], b.intr[b.cam], pts[b.point])
    err = np.linalg.norm(uv - b.uv, axis=1)
    return Solution(poses, pts, lengths, err, float(sol.cost))
