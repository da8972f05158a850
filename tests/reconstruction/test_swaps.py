"""Left/right checks of a triangulated skeleton: the limbs hang from their own side."""

from __future__ import annotations

import numpy as np
import pytest

from stereopose.reconstruction.triangulate import _asymmetry, _mirrored_pairs
from stereopose.sim.motion import pose
from stereopose.skeleton import LR_PAIRS, SWAP


def _skeleton(heading: float = 0.3, gait: float = 0.8, phase: float = 1.0) -> np.ndarray:
    return pose(
        1.75, np.array([[3.0, 2.0]]), np.array([heading]), np.array([gait]), np.array([phase])
    )


@pytest.mark.parametrize(
    "pairs",
    [[(7, 8), (9, 10)], [(9, 10)], [(13, 14), (15, 16)], [(15, 16)], [(7, 8), (9, 10), (15, 16)]],
)
@pytest.mark.parametrize("heading", [0.0, 1.3, -2.5])
def test_exchanged_limbs_are_found(pairs, heading):
    X = _skeleton(heading)
    bad = X.copy()
    for left, right in pairs:
        bad[:, [left, right]] = bad[:, [right, left]]
    swap = _mirrored_pairs(bad)
    expect = np.zeros((1, len(LR_PAIRS)), dtype=bool)
    for pair in pairs:
        expect[0, LR_PAIRS.index(pair)] = True
    np.testing.assert_array_equal(swap, expect)


@pytest.mark.parametrize("heading", [0.0, 1.3, -2.5])
def test_a_correct_skeleton_is_left_alone(heading):
    X = _skeleton(heading)
    assert not _mirrored_pairs(X).any()
    # a whole mirrored body is a body seen in a mirror: its face is behind its shoulders
    assert _mirrored_pairs(X[:, SWAP]).all()


def test_asymmetry():
    X = _skeleton()
    assert _asymmetry(X)[0] < 0.05
    bad = X.copy()
    bad[0, 9] = bad[0, 10]  # a wrist taken from the other arm: forearms of different lengths
    assert _asymmetry(bad)[0] > 0.15
    assert np.isnan(_asymmetry(np.full((1, 17, 3), np.nan))[0])
