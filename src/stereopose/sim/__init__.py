"""Synthetic substation scenes with ground truth, and accuracy metrics against them."""

from stereopose.sim.detections import DetectorNoise
from stereopose.sim.metrics import (
    Metrics,
    TrackingMetrics,
    evaluate,
    evaluate_tracking,
    match_people,
)
from stereopose.sim.scene import Scene, make_rig, simulate, truth_people3d

__all__ = [
    "DetectorNoise",
    "Metrics",
    "Scene",
    "TrackingMetrics",
    "evaluate",
    "evaluate_tracking",
    "make_rig",
    "match_people",
    "simulate",
    "truth_people3d",
]
