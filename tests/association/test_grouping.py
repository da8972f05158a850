"""Association: optimal pairwise assignment, consistent groups, permutation invariance."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.optimize import linear_sum_assignment

from stereopose.association.grouping import _assignment, group_detections


@settings(max_examples=200, deadline=None)
@given(st.integers(1, 6), st.integers(1, 6), st.integers(0, 2**32 - 1), st.booleans())
def test_assignment_is_optimal(rows, cols, seed, separated):
    rng = np.random.default_rng(seed)
    cost = rng.uniform(0, 1, (rows, cols))
    if separated:  # the common case: each row has a clear best column
        for i in range(min(rows, cols)):
            cost[i, i] = 1e-3 * rng.uniform()
    r, c = _assignment(cost)
    r_ref, c_ref = linear_sum_assignment(cost)
    assert len(r) == min(rows, cols)
    assert len(set(r.tolist())) == len(r) and len(set(c.tolist())) == len(c)
    assert cost[r, c].sum() == pytest.approx(cost[r_ref, c_ref].sum())


def _groups_as_sets(groups):
    return {frozenset(g.tolist()) for g in groups}


def test_groups_take_one_detection_per_camera_and_stay_consistent():
    # Three cameras, two people (A: 0, 2, 4; B: 1, 3, 5). Pair costs agree except one
    # misleading cheap pair (0, 3) that average linkage must refuse to merge into A's group.
    camera = np.array([0, 0, 1, 1, 2, 2])
    A, B = {0, 2, 4}, {1, 3, 5}
    cost = np.full((6, 6), 0.5)
    for g in (A, B):
        for i, j in itertools.permutations(g, 2):
            cost[i, j] = 0.02
    cost[0, 3] = cost[3, 0] = 0.01
    cost[camera[:, None] == camera[None, :]] = np.inf
    groups = group_detections(cost, camera, max_cost=0.12)
    assert _groups_as_sets(groups) == {frozenset(A), frozenset(B)}


def test_unmatched_detections_form_no_group():
    camera = np.array([0, 1, 2])
    cost = np.full((3, 3), 0.9)
    np.fill_diagonal(cost, np.inf)
    assert group_detections(cost, camera, max_cost=0.12) == []
    assert group_detections(np.zeros((0, 0)), np.zeros(0, int), max_cost=0.12) == []
