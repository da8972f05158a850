"""Running statistics: the median within its resolution, and a size that does not grow."""

from __future__ import annotations

import math
import sys

import numpy as np
import pytest

from stereopose.io.aggregates import RunningStats


@pytest.mark.parametrize("seed", range(8))
def test_median_within_half_a_bin_of_numpy(seed: int) -> None:
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 5000))
    values = rng.lognormal(mean=1.0, sigma=float(rng.uniform(0.2, 1.2)), size=n)
    stats = RunningStats()
    for chunk in np.array_split(values, int(rng.integers(1, 40))):
        stats.add(chunk)
    assert stats.count == n
    assert abs(stats.median - np.median(values)) <= stats.bin_width / 2 + 1e-12
    assert stats.mean == pytest.approx(values.mean(), rel=1e-12)


def test_small_samples_and_edges() -> None:
    s = RunningStats()
    assert math.isnan(s.median) and math.isnan(s.mean) and s.count == 0
    s.add(np.array([np.nan, np.inf, 1.0]))  # only finite values count
    assert s.count == 1 and s.median == pytest.approx(1.025)
    s.add([3.0])
    assert s.median == pytest.approx((1.025 + 3.025) / 2)  # the mean of the two middle bins
    big = RunningStats(bin_width=0.05, bins=100)  # top 5 px
    big.add([1.0, 7.0, 8.0])
    assert big.overflow == 2 and big.median == big.top  # above the top: reported as the top
    assert big.mean == pytest.approx(16 / 3)


def test_merge_is_adding_the_values() -> None:
    rng = np.random.default_rng(3)
    a, b = rng.uniform(0, 20, 300), rng.uniform(0, 20, 500)
    sa, sb, both = RunningStats(), RunningStats(), RunningStats()
    sa.add(a)
    sb.add(b)
    both.add(np.concatenate([a, b]))
    sa.merge(sb)
    assert sa.count == both.count and sa.median == both.median
    np.testing.assert_array_equal(sa.counts, both.counts)
    with pytest.raises(ValueError, match="same bins"):
        sa.merge(RunningStats(bins=10))


def test_size_is_fixed_over_10000_frames() -> None:
    rng = np.random.default_rng(0)
    s = RunningStats()
    s.add(rng.uniform(0, 10, 34))
    before = (s.nbytes, sys.getsizeof(s), s.counts.shape)
    for _ in range(10_000):
        s.add(rng.uniform(0, 10, 34))
    assert (s.nbytes, sys.getsizeof(s), s.counts.shape) == before
    assert s.count == 34 * 10_001
