"""Left/right checks of a triangulated skeleton: the limbs hang from their own side."""

from __future__ import annotations

import numpy as np
import pytest

from stereopose.reconstruction.labels import mirrored_pairs
from stereopose.reconstruction.triangulate import _implausibility
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
    swap = mirrored_pairs(bad)
    expect = np.zeros((1, len(LR_PAIRS)), dtype=bool)
    for pair in pairs:
        expect[0, LR_PAIRS.index(pair)] = True
    np.testing.assert_array_equal(swap, expect)


@pytest.mark.parametrize("heading", [0.0, 1.3, -2.5])
def test_a_correct_skeleton_is_left_alone(heading):
    X = _skeleton(heading)
    assert not mirrored_pairs(X).any()
    # a whole mirrored body is a body seen in a mirror: its face is behind its shoulders
    assert mirrored_pairs(X[:, SWAP]).all()


def test_implausibility():
    X = _skeleton()
    assert _implausibility(X)[0] < 0.05
    bad = X.copy()
    bad[0, 9] = bad[0, 10]  # a wrist taken from the other arm: forearms of different lengths
    assert _implausibility(bad)[0] > 0.15
    # symmetric but 2 m across the shoulders and hips: both sides moved apart by 0.8 m
    wide = X.copy()
    side = X[0, 6] - X[0, 5]
    side /= np.linalg.norm(side)
    wide[0, [6, 8, 10, 12, 14, 16]] += 0.8 * side
    wide[0, [5, 7, 9, 11, 13, 15]] -= 0.8 * side
    assert _implausibility(wide)[0] > 1.0
    assert _implausibility(np.full((1, 17, 3), np.nan))[0] == 0.0


@pytest.mark.parametrize("heading", [0.0, 1.3, -2.5])
def test_the_head_tells_the_front_when_the_shoulders_cannot(heading):
    # Shoulders displaced along their own axis (depth noise of two close views seen from the
    # side) put the face level with them; the nose ahead of the ears still shows the front.
    X = _skeleton(heading)
    side = X[0, 6] - X[0, 5]
    lead = X[0, :3].mean(0) - 0.5 * (X[0, 5] + X[0, 6])
    front = np.array([-side[1], side[0], 0.0]) / np.linalg.norm(side[:2])
    noisy = X.copy()
    noisy[0, [5, 6]] += lead @ front * front  # the shoulder line moved forward to the face
    assert not mirrored_pairs(noisy).any()
    assert mirrored_pairs(noisy[:, SWAP]).all()


def test_a_nose_off_the_head_does_not_turn_the_body():
    # a nose triangulated 0.35 m behind the face (an outlier in one of two views)
    X = _skeleton(0.7)
    side = X[0, 6] - X[0, 5]
    front = np.array([-side[1], side[0], 0.0]) / np.linalg.norm(side[:2])
    bad = X.copy()
    bad[0, 0] -= 0.35 * front
    assert not mirrored_pairs(bad).any()
    assert mirrored_pairs(bad[:, SWAP]).all()
