"""Floor position, heading and trajectory summaries."""

from __future__ import annotations

import numpy as np
import pytest

from stereopose.skeleton import joint_index
from stereopose.tracking.positioning import Trajectory, floor_position, heading_deg


def body(facing_deg: float) -> np.ndarray:
    """A person at (2, 3) facing `facing_deg` (counter-clockwise from +x)."""
    a = np.radians(facing_deg)
    front = np.array([np.cos(a), np.sin(a), 0.0])
    right = np.array([np.sin(a), -np.cos(a), 0.0])  # front rotated -90 degrees
    X = np.full((17, 3), np.nan)
    c = np.array([2.0, 3.0, 0.0])
    for side, s in (("left", -1), ("right", 1)):
        X[joint_index(f"{side}_shoulder")] = c + s * 0.2 * right + [0, 0, 1.4]
        X[joint_index(f"{side}_hip")] = c + s * 0.15 * right + [0, 0, 0.9]
    X[joint_index("nose")] = c + 0.1 * front + [0, 0, 1.6]
    return X[None]


@pytest.mark.parametrize("facing", [0.0, 90.0, -135.0, 179.0])
def test_heading_is_the_direction_the_body_faces(facing: float) -> None:
    assert heading_deg(body(facing))[0] == pytest.approx(facing)
    np.testing.assert_allclose(floor_position(body(facing)), [[2.0, 3.0]])


def test_heading_uses_the_hips_without_shoulders_and_is_nan_without_both() -> None:
    X = body(30.0)
    X[0, [joint_index("left_shoulder"), joint_index("right_shoulder")]] = np.nan
    assert heading_deg(X)[0] == pytest.approx(30.0)
    X[0, [joint_index("left_hip"), joint_index("right_hip")]] = np.nan
    assert np.isnan(heading_deg(X)[0])


def test_trajectory_accumulates_path_and_time() -> None:
    tr = Trajectory(7, first_frame=10, first_t=0.4, last_frame=10, last_t=0.4)
    for k, (x, y) in enumerate([(0, 0), (3, 4), (3, 4), (np.nan, np.nan), (6, 8)]):
        tr.add(11 + k, (11 + k) / 25, np.array([x, y], dtype=float))
    assert tr.path_m == pytest.approx(10.0)
    assert tr.frames_seen == 5 and tr.last_frame == 15
    assert tr.duration_s == pytest.approx(0.6 - 0.4)
    d = tr.as_dict()
    assert d["id"] == 7 and d["last_position"] == [6.0, 8.0]
