"""Who is near a hazard (zones.hazard): an energized, live zone's approach distance plus a
hand's motion until the step judged."""

from __future__ import annotations

import numpy as np
import pytest

from stereopose.zones import Zone
from stereopose.zones.hazard import HAND_SPEED_M_S, Hazards

BUSBAR = Zone(
    "busbar",
    "energized",
    np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]]),
    (1.5, 2.5),
    margin_m=0.3,
)
WORK = Zone("work", "work_area", np.array([[-5.0, -5], [5, -5], [5, 5], [-5, 5]]), (0.0, 2.5))


def person(x: float, hand_z: float = 1.0) -> np.ndarray:
    """17 joints on a vertical line at (x, 0.5), from the feet (z 0) up to 1.7 m; the right
    wrist (10) at hand_z beside him."""
    J = np.column_stack([np.full(17, x), np.full(17, 0.5), np.linspace(1.7, 0.0, 17)])
    J[10] = [x, 0.5, hand_z]
    return J


def test_within_the_approach_distance_plus_a_step_of_motion():
    hazards = Hazards([BUSBAR, WORK])
    assert hazards.names == ("busbar",)  # a work area is no hazard
    # the right wrist at z 1.0 is 0.5 m below the prism's bottom; his head 0.2 m to its
    # side at x = 1.2 is 0.2 m from its corner edge (z 1.7 is within the band)
    far, head_near, hand_in = person(3.0), person(1.2), person(0.5, hand_z=2.0)
    got = hazards.near(np.stack([far, head_near, hand_in]), ahead_s=0.0)
    assert got.tolist() == [False, True, True]
    # 1.35 m away: beyond 0.3 m, within 0.3 + 2 m/s * 0.6 s
    away = person(2.35)
    assert not hazards.near(away[None], 0.0).any()
    assert not hazards.near(away[None], 0.5).any()  # 0.3 + 1.0 m
    assert hazards.near(away[None], 0.6).all()
    assert HAND_SPEED_M_S == 2.0


def test_a_dead_zone_is_no_hazard_and_unknown_is_live():
    dead: set[str] = set()
    hazards = Hazards([BUSBAR], dead=lambda: dead)
    inside = person(0.5, hand_z=2.0)[None]
    assert hazards.near(inside, 0.0).all()
    dead.add("busbar")  # asked again at every call
    assert not hazards.near(inside, 0.0).any()
    dead.clear()
    assert hazards.near(inside, 0.0).all()


def test_missing_joints_and_no_zone():
    hazards = Hazards([BUSBAR])
    nobody = np.full((2, 17, 3), np.nan)
    assert hazards.near(nobody, 1.0).tolist() == [False, False]
    some = person(1.2)
    some[:8] = np.nan  # his upper body not reconstructed: his hips (z 0.85) are 0.68 m away
    some[10] = np.nan
    assert not hazards.near(some[None], 0.0).any()
    assert hazards.near(some[None], 0.2).all()  # 0.3 + 0.4 m
    assert hazards.near(np.zeros((0, 17, 3)), 1.0).shape == (0,)
    none = Hazards([WORK])
    assert not none and not none.near(person(0.5, 2.0)[None], 1.0).any()
    with pytest.raises(ValueError, match="shape"):
        hazards.near(np.zeros((17, 3)), 0.0)
    with pytest.raises(ValueError, match="speed"):
        Hazards([BUSBAR], speed_m_s=float("nan"))


def test_a_zone_with_no_approach_margin_counts_its_prism_and_the_motion():
    bare = Zone("bare", "energized", BUSBAR.polygon, BUSBAR.z)
    hazards = Hazards([bare])
    side = person(1.1)  # his head 0.1 m beside the prism
    assert not hazards.near(side[None], 0.0).any()
    assert hazards.near(side[None], 0.06).all()  # 2 m/s for 60 ms: 0.12 m
