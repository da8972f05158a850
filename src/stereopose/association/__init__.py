"""Who is who across cameras: affinities between 2D people and consistent groups."""

from stereopose.association.affinity import (
    Detections,
    PairDistances,
    epipolar_costs,
    epipolar_distances,
)
from stereopose.association.grouping import group_detections

__all__ = [
    "Detections",
    "PairDistances",
    "epipolar_costs",
    "epipolar_distances",
    "group_detections",
]
