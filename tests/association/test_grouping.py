"""Association: optimal pairwise assignment, consistent groups, permutation invariance."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from scipy.optimize import linear_sum_assignment

from stereopose.association.grouping import group_detections, pairwise_matches


@st.composite
def frames(draw):
    """Detections per camera (counts), their pair costs, and, for the separated case, which
    person each detection is in its camera (a permutation per camera)."""
    counts = draw(st.lists(st.integers(0, 5), min_size=2, max_size=5))
    N = sum(counts)
    cost = draw(arrays(np.float64, (N, N), elements=st.floats(0.0, 0.2)))
    person = np.array([p for c in counts for p in draw(st.permutations(range(c)))], dtype=np.int64)
    return counts, cost, person, draw(st.booleans())


@settings(max_examples=200, deadline=None)
@given(frames())
def test_pairwise_matches_are_optimal_per_camera_pair(frame):
    """Same total cost per camera pair as the Hungarian algorithm run pair by pair."""
    counts, cost, person, separated = frame
    camera = np.repeat(np.arange(len(counts)), counts)
    N = camera.size
    if separated:  # the common case: people far apart, one clear partner each
        cost = np.where(person[:, None] == person[None, :], 0.01 * cost, cost + 0.5)
    cost = np.minimum(cost, cost.T)
    cost[camera[:, None] == camera[None, :]] = np.inf
    rows = pairwise_matches(cost, camera, max_cost=np.inf)
    got: dict[tuple[int, int], float] = {}
    for n, m, c in rows:
        key = (int(camera[int(n)]), int(camera[int(m)]))
        got[key] = got.get(key, 0.0) + c
    for a, b in itertools.combinations(range(len(counts)), 2):
        ia, ib = np.flatnonzero(camera == a), np.flatnonzero(camera == b)
        if ia.size == 0 or ib.size == 0:
            assert (a, b) not in got
            continue
        r, c = linear_sum_assignment(cost[np.ix_(ia, ib)])
        assert got[(a, b)] == pytest.approx(cost[ia[r], ib[c]].sum())
    for n, m, _ in rows:  # one-to-one
        assert camera[int(n)] != camera[int(m)]
    assert len({int(n) for n, *_ in rows} | set()) <= N


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


def test_costs_beyond_max_cost_do_not_steer_the_assignment():
    # Detections 0, 1 in camera 0 and 2, 3 in camera 1; only (0, 2) is within max_cost. Summed
    # over the pair, (0, 3) + (1, 2) is cheaper than (0, 2) + (1, 3), but both of its matches
    # lie beyond max_cost and would be dropped: the one possible match must be kept.
    camera = np.array([0, 0, 1, 1])
    cost = np.full((4, 4), np.inf)
    for (n, m), c in {(0, 2): 0.05, (1, 3): 0.5, (0, 3): 0.2, (1, 2): 0.3}.items():
        cost[n, m] = cost[m, n] = c
    rows = pairwise_matches(cost, camera, max_cost=0.12)
    assert [(int(n), int(m)) for n, m, _ in rows] == [(0, 2)]
    assert [g.tolist() for g in group_detections(cost, camera, max_cost=0.12)] == [[0, 2]]
