"""The rig from people put in the site's world: its scale, its floor, its axes; and how much
of each camera's view the walkers covered.

Scale, from one of:
- two cameras' measured distance (centre to centre);
- the walkers' standing height H: a standing adult's eyes are at 0.936 H (anthropometric
  tables), the COCO ankle (the lateral malleolus) `ankle_m` above the floor, so the median
  height of the eyes above the lower ankle of a walking person is 0.936 H - ankle_m;
- surveyed points clicked in the views: triangulated with the rig, then one similarity
  (Umeyama) onto their surveyed positions, which also gives the world frame.

Floor: the plane of the lower ankle of each person at each frame, z = 0 `ankle_m` under it,
z up (the cameras' side). Without surveyed points, x runs along the first camera's view
direction on the floor and the origin is the floor under that camera.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import cv2
import numpy as np

from stereopose.calibration.poses import camera_with_pose
from stereopose.errors import CalibrationError
from stereopose.geometry.camera import undistort_normalized
from stereopose.geometry.triangulation import triangulate_dlt
from stereopose.types import Rig

if TYPE_CHECKING:
    from stereopose.calibration.surveyed import Survey

__all__ = ["EYE_FRACTION", "coverage_advice", "to_world"]

EYE_FRACTION = 0.936  # eye height over standing height
ANKLES, EYES = (15, 16), (1, 2)
GRID = (4, 3)  # columns, rows of the view judged for coverage


def _moved(rig: Rig, s: float, Q: np.ndarray, u: np.ndarray) -> Rig:
    """The rig in the frame X_new = s Q X_old + u."""
    out = []
    for c in rig:
        R = c.R @ Q.T
        t = s * c.translation - R @ u
        out.append(camera_with_pose(c, np.concatenate([cv2.Rodrigues(R)[0].ravel(), t])))
    return Rig(tuple(out))


def _normal(points: np.ndarray) -> np.ndarray:
    """Unit normal of the points' plane, the worst fifth trimmed twice."""
    keep = np.ones(len(points), dtype=bool)
    n = np.zeros(3)  # each pass's
    for _ in range(3):
        c = points[keep].mean(axis=0)
        n = np.linalg.svd(points[keep] - c)[2][2]
        dist = np.abs((points - c) @ n)
        keep = dist <= np.quantile(dist, 0.8)
    return n


def _heights(X: np.ndarray, n: np.ndarray) -> np.ndarray:
    """(G, 2) each person's ankles along n (inf where missing)."""
    return np.where(np.isfinite(X[:, ANKLES, 0]), X[:, ANKLES] @ n, np.inf)


def _umeyama(src: np.ndarray, dst: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """s, Q, u with dst ~ s Q src + u (least squares)."""
    ms, md = src.mean(0), dst.mean(0)
    a, b = src - ms, dst - md
    U, S, Vt = np.linalg.svd(b.T @ a / len(src))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    Q = U @ D @ Vt
    s = float(np.trace(np.diag(S) @ D) / (a**2).sum(axis=1).mean())
    return s, Q, md - s * Q @ ms


def _survey_frame(rig: Rig, survey: Survey) -> tuple[Rig, str]:
    names = rig.names
    src, dst, used = [], [], []
    for p, xyz in survey.world.items():
        seen = [
            (i, survey.clicks[n][p]) for i, n in enumerate(names) if p in survey.clicks.get(n, {})
        ]
        if len(seen) < 2:
            continue
        xy = np.stack([undistort_normalized(uv[None], rig[i])[0] for i, uv in seen])
        P = np.stack([rig[i].P for i, _ in seen])
        src.append(triangulate_dlt(xy, P, np.ones(len(seen))))
        dst.append(xyz)
        used.append(p)
    if len(src) < 3:
        raise CalibrationError(
            f"{survey.path}: {len(src)} surveyed point(s) seen by two cameras or more "
            f"({', '.join(used) or 'none'}); at least 3 are needed for the scale and the frame"
        )
    s, Q, u = _umeyama(np.array(src), np.array(dst))
    return _moved(rig, s, Q, u), f"surveyed points ({len(src)})"


def to_world(
    rig: Rig,
    X: np.ndarray,
    *,
    distance: tuple[str, str, float] | None = None,
    height_m: float | None = None,
    survey: Survey | None = None,
    ankle_m: float = 0.08,
) -> tuple[Rig, str]:
    """The rig (any frame and scale) and its people's joints X (G, 17, 3) in that frame ->
    the rig in the site's world (see the module), and where its scale came from."""
    if survey is not None:
        return _survey_frame(rig, survey)
    ankles = X[:, ANKLES].reshape(-1, 3)
    ankles = ankles[np.isfinite(ankles).all(1)]
    if len(ankles) < 20:
        raise CalibrationError(f"{len(ankles)} ankles reconstructed: too few to find the floor")
    n = _normal(ankles)
    centres = np.stack([c.center for c in rig])
    if np.mean(centres @ n) < np.median(ankles @ n):
        n = -n
    # each person's lower ankle (the foot on the floor), then the plane of those
    low = np.take_along_axis(X[:, ANKLES], np.argmin(_heights(X, n), 1)[:, None, None], 1)[:, 0]
    low = low[np.isfinite(low).all(1)]
    n2 = _normal(low)
    n = n2 if n2 @ n > 0 else -n2
    d = float(np.median(low @ n))
    if distance is not None:
        a, b, metres = distance
        s = metres / float(np.linalg.norm(rig[a].center - rig[b].center))
        scale_from = f"the distance {a}-{b} ({metres:g} m)"
    else:
        assert height_m is not None  # the scale from one or the other
        eyes = 0.5 * (X[:, EYES[0]] + X[:, EYES[1]]) @ n  # NaN unless both eyes
        rise = eyes - _heights(X, n).min(axis=1)
        rise = rise[np.isfinite(rise)]
        if len(rise) < 10:
            raise CalibrationError(
                f"{len(rise)} people seen with eyes and ankles: too few for --height"
            )
        s = (EYE_FRACTION * height_m - ankle_m) / float(np.median(rise))
        scale_from = f"the walkers' height ({height_m:g} m)"
    c0 = rig[0].center
    origin = c0 - (c0 @ n - d) * n - (ankle_m / s) * n
    view = rig[0].R[2]
    x = view - (view @ n) * n
    if np.linalg.norm(x) < 1e-6:
        x = rig[0].R[0] - (rig[0].R[0] @ n) * n
    x /= np.linalg.norm(x)
    Q = np.stack([x, np.cross(n, x), n])
    return _moved(rig, s, Q, -s * Q @ origin), scale_from


def coverage_advice(rig: Rig, uv: dict[str, np.ndarray], min_obs: int = 20) -> tuple[dict, list]:
    """Per camera the share of its view's cells (GRID) that look at the ground near person
    height and hold `min_obs` joints or more; advice naming where to walk where it is under
    half."""
    cover, advice = {}, []
    for cam in rig:
        w, h = cam.size
        cols, rows = GRID
        counts = np.zeros((rows, cols), dtype=int)
        pts = uv.get(cam.name, np.zeros((0, 2)))
        if len(pts):
            ci = np.clip((pts[:, 0] / w * cols).astype(int), 0, cols - 1)
            ri = np.clip((pts[:, 1] / h * rows).astype(int), 0, rows - 1)
            np.add.at(counts, (ri, ci), 1)
        walkable, empty = 0, []
        for r in range(rows):
            for c in range(cols):
                centre = np.array([[(c + 0.5) * w / cols, (r + 0.5) * h / rows]])
                ray = cam.R.T @ np.append(undistort_normalized(centre, cam)[0], 1.0)
                if ray[2] >= -1e-6:
                    continue  # above the horizon
                k = (1.0 - cam.center[2]) / ray[2]  # where it meets 1 m above the floor
                if not 0 < k < 200.0 / np.linalg.norm(ray):
                    continue
                walkable += 1
                if counts[r, c] < min_obs:
                    empty.append(cam.center + k * ray)
        # a camera at or below person height (no cell meets that plane): its whole view
        share = 1.0 - len(empty) / walkable if walkable else float(np.mean(counts >= min_obs))
        cover[cam.name] = share
        if share < 0.5 and empty:
            where = ", ".join(f"({p[0]:.1f}, {p[1]:.1f})" for p in empty[:4])
            advice.append(
                f"camera {cam.name}: the walkers covered {100 * share:.0f}% of its view; "
                f"walk near {where} (site metres) and calibrate again"
            )
    return cover, advice
