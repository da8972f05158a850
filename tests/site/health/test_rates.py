"""RateWindow: counts over the last span_s in fixed buckets; rates that forget the past, in
memory that never grows."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from stereopose.site.health.rates import RateWindow


def test_the_rate_follows_the_last_window_not_the_total():
    w = RateWindow(span_s=60.0, buckets=12)
    assert w.rate(0.0) is None and w.total(0.0) == 0
    for i in range(1200):  # 2 minutes at 10 per second
        w.add(i / 10)
    assert w.rate(119.9) == pytest.approx(10.0, rel=0.02)
    for i in range(60):  # then a minute at 1 per second
        w.add(120.0 + i)
    assert w.rate(179.9) == pytest.approx(1.0, rel=0.1)  # the fast minutes are forgotten
    assert w.covered(179.9) <= 60.0


def test_the_first_seconds_divide_by_the_time_passed_only():
    w = RateWindow(span_s=60.0, buckets=12)
    for i in range(51):
        w.add(100.0 + i / 10)
    assert w.covered(105.0) == pytest.approx(5.0)
    assert w.rate(105.0) == pytest.approx(51 / 5.0)


def test_bad_arguments_and_counts_out_of_the_window():
    with pytest.raises(ValueError, match="span_s"):
        RateWindow(span_s=0.0)
    with pytest.raises(ValueError, match="bucket"):
        RateWindow(buckets=0)
    w = RateWindow(span_s=10.0, buckets=5)
    w.add(100.0, 3)
    w.add(float("nan"))
    w.add(50.0)  # far older than the window: its slot holds a newer bucket
    assert w.total(100.0) == 3
    assert w.total(200.0) == 0  # all of it gone


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(st.floats(0.0, 3.0), st.integers(1, 5)), max_size=80))
def test_the_total_is_what_came_within_the_window(steps):
    w = RateWindow(span_s=10.0, buckets=10)
    t, kept = 0.0, []
    for dt, n in steps:
        t += dt
        w.add(t, n)
        kept.append((t, n))
        # every count of the last 9 s is in, none older than 10 s
        recent = sum(k for at, k in kept if at > t - 9.0)
        within = sum(k for at, k in kept if at > t - 10.0 - 1e-9)
        assert recent <= w.total(t) <= within
    assert len(w._counts) == 10
