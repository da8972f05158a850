"""Who is who across cameras: affinities between 2D people and consistent groups."""

from stereopose.association.affinity import Detections, epipolar_costs
from stereopose.association.grouping import group_detections

__all__ = ["Detections", "epipolar_costs", "group_detections"]
