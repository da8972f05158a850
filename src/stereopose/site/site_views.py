"""The site seen by the cameras, for the console's Site tab: each zone's prism projected into
every camera (with its lens), and a click on a camera's picture back on the floor.

`views(site, rig)`: per camera its size and, per zone, the prism's edges as polylines in
fractions of the picture (x right, y down; each edge sampled so that a distorted lens bends it;
what is behind the camera or far outside the picture left out). `floor_point(camera, fx, fy,
z)`: where the ray through that point of the picture meets the plane at height z (metres), or
None when it never does in front of the camera.
"""

from __future__ import annotations

import numpy as np

from stereopose.fence import Site
from stereopose.geometry.camera import project, undistort_normalized
from stereopose.types import Camera, Rig

__all__ = ["floor_point", "views"]

SAMPLES = 8  # points per edge
OUTSIDE = 0.5  # a polyline's points kept within this far outside the picture (fractions)


def _edges(polygon: np.ndarray, z: tuple[float, float]) -> list[np.ndarray]:
    """The prism's 3D edges: the bottom and top rings and the uprights, as (2, 3) segments."""
    out = []
    n = len(polygon)
    for k in range(n):
        a, b = polygon[k], polygon[(k + 1) % n]
        for h in z:
            out.append(np.array([[a[0], a[1], h], [b[0], b[1], h]]))
        out.append(np.array([[a[0], a[1], z[0]], [a[0], a[1], z[1]]]))
    return out


def _polylines(uv: np.ndarray, size: tuple[float, float]) -> list[list[list[float]]]:
    """Sampled pixels -> runs of picture fractions, broken where a point is missing."""
    w, h = size
    f = uv / np.array([w, h])
    ok = np.asarray(np.isfinite(f).all(axis=1) & (np.abs(f - 0.5) <= 0.5 + OUTSIDE).all(axis=1))
    runs, run = [], []
    for good, p in zip(ok, f, strict=True):
        if good:
            run.append([round(float(p[0]), 4), round(float(p[1]), 4)])
        elif run:
            runs.append(run)
            run = []
    if run:
        runs.append(run)
    return [r for r in runs if len(r) >= 2]


def views(site: Site, rig: Rig) -> dict[str, object]:
    """{"cameras": [{"name", "size", "zones": [{"name", "kind", "lines"}]}]} (see the module)."""
    t = np.linspace(0.0, 1.0, SAMPLES)[:, None]
    segments = {
        z.name: np.concatenate(
            [a[0] + t * (a[1] - a[0]) for a in _edges(np.asarray(z.polygon), z.z)]
        ).reshape(-1, SAMPLES, 3)
        for z in site.zones
    }
    out = []
    for cam in rig:
        zones = []
        for z in site.zones:
            uv = project(segments[z.name], cam)  # (edges, SAMPLES, 2), NaN behind
            lines = [line for edge in uv for line in _polylines(edge, cam.size)]
            zones.append({"name": z.name, "kind": z.kind, "lines": lines})
        out.append(
            {"name": cam.name, "size": [float(cam.size[0]), float(cam.size[1])], "zones": zones}
        )
    return {"cameras": out}


def floor_point(camera: Camera, fx: float, fy: float, z: float = 0.0) -> tuple[float, float] | None:
    """The point at height z (metres) seen at (fx, fy) of the picture (fractions), or None."""
    w, h = camera.size
    xy = undistort_normalized(np.array([[fx * w, fy * h]], dtype=np.float64), camera)[0]
    if not np.isfinite(xy).all():
        return None
    direction = camera.R.T @ np.array([xy[0], xy[1], 1.0])
    if abs(direction[2]) < 1e-9:
        return None
    s = (z - camera.center[2]) / direction[2]
    if s <= 0:
        return None
    p = camera.center + s * direction
    return float(p[0]), float(p[1])
