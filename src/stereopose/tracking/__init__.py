"""Identities over time, online smoothing and floor positions of reconstructed people.

The tracker (numba loops, SciPy's assignment) is imported when first asked for, so reading a
trajectory or a floor position costs nothing more.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from stereopose.tracking.positioning import Trajectory, floor_position, heading_deg

if TYPE_CHECKING:
    from stereopose.tracking.tracker import Tracker

__all__ = ["Tracker", "Trajectory", "floor_position", "heading_deg"]


def __getattr__(name: str) -> object:
    if name == "Tracker":
        from stereopose.tracking.tracker import Tracker

        return Tracker
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
