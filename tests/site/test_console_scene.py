"""The console's scene (site.scene): an energized zone with somebody inside is in alarm while
its breakers read live, and shows its state from them; dead by its breakers, no alarm. The
states come from the `power` the scene is given when it is made (serve: the service's zone
states now, whichever sources run), never set on it later."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from stereopose.fence import load_site
from stereopose.io.sinks.base import FrameResult
from stereopose.site.scene import SceneState
from stereopose.types import Event, People3D

SITE = """fps = 25.0

[[zones]]
name = "bay2"
kind = "energized"
polygon = [[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]]
z = [0.0, 2.0]
margin_m = 0.3
"""


def _inside(frame: int) -> FrameResult:
    """Person 7 standing in bay2 at `frame`, and its enter event."""
    J = np.zeros((1, 17, 3))
    J[0, :, 0], J[0, :, 1], J[0, :, 2] = 0.5, 0.5, np.linspace(1.7, 0.05, 17)
    t = frame / 25.0
    people = People3D(
        frame,
        J,
        np.ones((1, 17)),
        np.full(1, 7),
        np.zeros((1, 17)),
        np.full((1, 17), 2),
        np.full((1, 2), -1),
    )
    enter = Event(
        t=t, frame=frame, person=7, zone="bay2", kind="energized", type="enter", onset_t=t
    )
    return FrameResult(frame, t, {}, people, [enter])


def test_the_scenes_zones_follow_the_breakers_it_was_given(tmp_path: Path) -> None:
    path = tmp_path / "site.toml"
    path.write_text(SITE)
    breakers = {"bay2": {"state": "live"}}
    scene = SceneState(load_site(path), power=lambda: dict(breakers))
    scene.update(_inside(1), wall_start=1.8e9)
    (zone,) = scene.zones()["zones"]
    assert zone["state"] == "alarm" and zone["occupants"] == [7]
    assert zone["power"] == {"state": "live"}
    breakers["bay2"] = {"state": "dead"}
    (zone,) = scene.zones()["zones"]
    assert zone["state"] != "alarm" and zone["power"] == {"state": "dead"}
    # without breakers read: the zone is live as drawn
    (zone,) = SceneState(load_site(path)).zones()["zones"]
    assert zone["power"] is None
