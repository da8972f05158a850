"""Floor polygons: signed area and the self-intersection test, over every edge pair at once.

Polygons are (V, 2) arrays of vertices in metres (world x-y), either orientation, not closed
(the last vertex connects back to the first).
"""

from __future__ import annotations

import numpy as np


def polygon_area(poly: np.ndarray) -> float:
    """Signed area (shoelace), positive for counter-clockwise vertices."""
    x, y = poly[:, 0], poly[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(np.roll(x, -1), y))


def _cross(o: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return (a[..., 0] - o[..., 0]) * (b[..., 1] - o[..., 1]) - (a[..., 1] - o[..., 1]) * (
        b[..., 0] - o[..., 0]
    )


def _on(a: np.ndarray, b: np.ndarray, c: np.ndarray, d: np.ndarray) -> np.ndarray:
    """c on segment ab, given collinear (d == 0)."""
    return (
        (d == 0)
        & (np.minimum(a[..., 0], b[..., 0]) <= c[..., 0])
        & (c[..., 0] <= np.maximum(a[..., 0], b[..., 0]))
        & (np.minimum(a[..., 1], b[..., 1]) <= c[..., 1])
        & (c[..., 1] <= np.maximum(a[..., 1], b[..., 1]))
    )


def _segments_meet(p1: np.ndarray, p2: np.ndarray, q1: np.ndarray, q2: np.ndarray) -> np.ndarray:
    """Whether segments p1p2 and q1q2 share a point (touching and overlapping included),
    broadcast over their leading axes."""
    d1, d2 = _cross(q1, q2, p1), _cross(q1, q2, p2)
    d3, d4 = _cross(p1, p2, q1), _cross(p1, p2, q2)
    proper = ((d1 > 0) != (d2 > 0)) & ((d3 > 0) != (d4 > 0))
    proper &= (d1 != 0) & (d2 != 0) & (d3 != 0) & (d4 != 0)
    return (
        proper
        | _on(q1, q2, p1, d1)
        | _on(q1, q2, p2, d2)
        | _on(p1, p2, q1, d3)
        | _on(p1, p2, q2, d4)
    )


def self_intersection(poly: np.ndarray, rows: int = 128) -> tuple[int, int] | None:
    """The first pair of non-adjacent edges (i, j), i < j, that meet, or None for a simple
    polygon (V, 2). Every pair is tested at once, `rows` edges i at a time (memory)."""
    V = poly.shape[0]
    a, b = poly, np.roll(poly, -1, axis=0)
    j = np.arange(V)[None]
    for start in range(0, V, rows):
        i = np.arange(start, min(start + rows, V))[:, None]
        # adjacent edges share a vertex by construction
        pairs = (j > i + 1) & ~((i == 0) & (j == V - 1))
        meet = _segments_meet(a[i], b[i], a[None], b[None]) & pairs
        if meet.any():
            k, m = np.argwhere(meet)[0]
            return int(i[k, 0]), int(m)
    return None
