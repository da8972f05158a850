"""Synthetic substation scenes with ground truth, and accuracy metrics against them."""

from stereopose.sim.detections import DetectorNoise
from stereopose.sim.metrics import Metrics, evaluate, match_people
from stereopose.sim.scene import Scene, make_rig, simulate, truth_people3d

__all__ = [
    "DetectorNoise",
    "Metrics",
    "Scene",
    "evaluate",
    "make_rig",
    "match_people",
    "simulate",
    "truth_people3d",
]
