"""The zones' geometry, vectorised over every joint of every person and every zone at once:
inside the prism, distance to it, and which people come near which zones."""

from __future__ import annotations

import numpy as np

from stereopose.zones.zone import Zone

__all__ = ["ZoneGeometry"]


class ZoneGeometry:
    """All zones' edges in padded arrays, for vectorised tests of many points.

    test(points, zones) -> inside, distance: for points (K, J, 3) each tested against one zone
    zones[k]: (K, J) inside the prism (edges and faces count as inside) and distance to it in
    metres (0 inside); NaN points are inside nothing and infinitely far.
    inside(points) / distance(points): (N, 3) points against every zone, (N, Z).
    near(boxes, reach): which people's boxes come near which zones' boxes.
    """

    def __init__(self, zones: tuple[Zone, ...]) -> None:
        self.zones = zones
        V = max(z.polygon.shape[0] for z in zones)
        # edges (Z, V, 2) from a to b; missing edges of smaller polygons are NaN (they never
        # straddle a point and have no distance)
        self.a = np.full((len(zones), V, 2), np.nan)
        self.b = np.full((len(zones), V, 2), np.nan)
        for k, zone in enumerate(zones):
            p = zone.polygon
            self.a[k, : len(p)] = p
            self.b[k, : len(p)] = np.roll(p, -1, axis=0)
        self.ab = self.b - self.a
        self.len2 = np.maximum((self.ab**2).sum(-1), 1e-18)
        with np.errstate(invalid="ignore", divide="ignore"):
            slope = self.ab[..., 0] / self.ab[..., 1]  # dx/dy, inf for horizontal edges
        # one table gathered per test: (Z, V, 7) ax, ay, by, abx, aby, 1/len2, dx/dy
        self.table = np.stack(
            [
                self.a[..., 0],
                self.a[..., 1],
                self.b[..., 1],
                self.ab[..., 0],
                self.ab[..., 1],
                1.0 / self.len2,
                slope,
            ],
            axis=-1,
        )
        self.zlo = np.array([z.z[0] for z in zones])
        self.zhi = np.array([z.z[1] for z in zones])
        self.lo = np.array([z.polygon.min(0) for z in zones])  # floor boxes (Z, 2)
        self.hi = np.array([z.polygon.max(0) for z in zones])

    def test(
        self, points: np.ndarray, zones: np.ndarray, tol: float = 1e-9
    ) -> tuple[np.ndarray, np.ndarray]:
        """Points (K, J, 3), each row against zone zones[k] -> inside (K, J), distance (K, J)."""
        px, py, pz = points[..., 0:1], points[..., 1:2], points[..., 2]  # (K, J, 1)
        tab = self.table[zones][:, None]  # (K, 1, V, 7)
        ax, ay, by, abx, aby = tab[..., 0], tab[..., 1], tab[..., 2], tab[..., 3], tab[..., 4]
        with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
            # crossing number (padding edges are NaN: they never straddle), NaN points cross
            # nothing and lie at NaN distance, turned to inf below
            dy = py - ay
            crossing = ((ay > py) != (by > py)) & (px < ax + dy * tab[..., 6])
            odd = np.logical_xor.reduce(crossing, axis=-1)
            dx = px - ax
            t = np.clip((dx * abx + dy * aby) * tab[..., 5], 0.0, 1.0)
            ex, ey = t * abx - dx, t * aby - dy
            edge_d = np.sqrt(np.fmin.reduce(ex * ex + ey * ey, axis=-1))
            floor = odd | (edge_d <= tol)
            dz = np.maximum(
                np.maximum(self.zlo[zones][:, None] - pz, pz - self.zhi[zones][:, None]), 0.0
            )
            inside = floor & (dz == 0.0)
            dist = np.hypot(np.where(floor, 0.0, edge_d), dz)
        return inside, np.where(dist == dist, dist, np.inf)

    def distance(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(N, 3) points against every zone -> inside (N, Z), distance (N, Z)."""
        Z = len(self.zones)
        inside, dist = self.test(np.broadcast_to(points[None], (Z, *points.shape)), np.arange(Z))
        return inside.T, dist.T

    def inside(self, points: np.ndarray) -> np.ndarray:
        """(N, 3) points against every zone -> (N, Z) inside."""
        return self.distance(points)[0]

    def near(self, boxes: np.ndarray, reach: np.ndarray) -> np.ndarray:
        """(P, Z) whether boxes (P, 2, 3) [min, max] come within reach (Z,) metres of each
        zone's bounding box: only those pairs can be inside or near each other."""
        lo, hi = boxes[:, 0], boxes[:, 1]
        r = reach[None]
        with np.errstate(invalid="ignore"):
            return (
                (lo[:, None, 0] <= self.hi[None, :, 0] + r)
                & (hi[:, None, 0] >= self.lo[None, :, 0] - r)
                & (lo[:, None, 1] <= self.hi[None, :, 1] + r)
                & (hi[:, None, 1] >= self.lo[None, :, 1] - r)
                & (lo[:, None, 2] <= self.zhi[None] + r)
                & (hi[:, None, 2] >= self.zlo[None] - r)
            )
