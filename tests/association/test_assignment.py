"""The compiled assignment gives SciPy's assignments, ties and large fill costs included."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from scipy.optimize import linear_sum_assignment as scipy_lsa

from stereopose.association.assignment import linear_sum_assignment

# small integer-valued costs tie often; 1e9 stands for a forbidden pair, as the callers use it
costs = st.integers(1, 9).flatmap(
    lambda r: st.integers(1, 9).flatmap(
        lambda c: arrays(
            np.float64,
            (r, c),
            elements=st.one_of(
                st.sampled_from([0.0, 1.0, 2.0, 1e9]), st.floats(0, 10, allow_nan=False)
            ),
        )
    )
)


@settings(max_examples=300, deadline=None)
@given(costs)
def test_same_assignment_as_scipy(cost):
    rows, cols = linear_sum_assignment(cost)
    want_rows, want_cols = scipy_lsa(cost)
    np.testing.assert_array_equal(rows, want_rows)
    np.testing.assert_array_equal(cols, want_cols)


def test_constant_and_empty_matrices():
    rows, cols = linear_sum_assignment(np.ones((3, 5)))
    assert rows.tolist() == [0, 1, 2] and cols.tolist() == [0, 1, 2]
    rows, cols = linear_sum_assignment(np.zeros((0, 4)))
    assert rows.size == cols.size == 0


def test_bad_costs_are_clear_errors():
    with pytest.raises(ValueError, match="NaN"):
        linear_sum_assignment(np.array([[0.0, np.nan]]))
    with pytest.raises(ValueError, match="infeasible"):
        linear_sum_assignment(np.array([[np.inf, np.inf], [0.0, 1.0]]))
    with pytest.raises(ValueError, match=r"cost must have shape \(\*, \*\)"):
        linear_sum_assignment(np.zeros(3))
