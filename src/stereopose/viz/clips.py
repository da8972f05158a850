"""How event clips are drawn: each kept frame with the detections and the 3D people
reprojected with their ids (viz.overlay), for io.sinks.clips.ClipSink."""

from __future__ import annotations

import numpy as np

from stereopose.io.sinks.clips import Draw
from stereopose.types import People2D, People3D, Rig
from stereopose.viz.overlay import draw_overlay


def clip_drawer(rig: Rig) -> Draw:
    """A ClipSink `draw` for the cameras of `rig`: draw_overlay at the clip's scale."""

    def draw(
        camera: str,
        image: np.ndarray,
        people2d: People2D | None,
        people3d: People3D,
        scale: float,
        label: str,
    ) -> np.ndarray:
        return draw_overlay(image, rig[camera], people2d, people3d, scale, label)

    return draw
