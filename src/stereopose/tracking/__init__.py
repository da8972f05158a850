"""Identities over time, online smoothing and floor positions of reconstructed people."""

from stereopose.tracking.positioning import Trajectory, floor_position, heading_deg
from stereopose.tracking.tracker import Tracker

__all__ = ["Tracker", "Trajectory", "floor_position", "heading_deg"]
