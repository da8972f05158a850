"""Running statistics of fixed size, for runs of any length.

A run that lasts weeks must not keep a value per frame: `RunningStats` keeps a count, a sum
and a fixed-bin histogram, so its memory is the same after ten frames and after ten million.
"""

from __future__ import annotations

import math

import numpy as np


class RunningStats:
    """Count, mean and median of non-negative values (reprojection errors in pixels, say).

    The median comes from a histogram of `bins` bins of `bin_width` (0.05 px by default, from 0
    to 200 px) plus one overflow count: it is the mean of the centres of the bins holding the
    two middle values, so it lies within half a bin (0.025 px by default) of the exact median
    whenever the middle values are below the histogram's top (`bins * bin_width`); when they are
    above it, the median is reported as the top (a lower bound). The mean is exact (a running
    sum); negative values count in the first bin.
    """

    __slots__ = ("bin_width", "count", "counts", "overflow", "total")

    def __init__(self, bin_width: float = 0.05, bins: int = 4000) -> None:
        self.bin_width = float(bin_width)
        self.counts = np.zeros(int(bins), dtype=np.int64)
        self.overflow = 0
        self.count = 0
        self.total = 0.0

    @property
    def top(self) -> float:
        """The histogram's upper edge: values at or above it are counted as overflow."""
        return self.bin_width * len(self.counts)

    def add(self, values: np.ndarray) -> None:
        """Add values (any shape); NaN and infinite values are ignored."""
        v = np.asarray(values, dtype=np.float64).reshape(-1)
        v = v[np.isfinite(v)]
        if not v.size:
            return
        self.count += int(v.size)
        self.total += float(v.sum())
        idx = np.floor(np.maximum(v, 0.0) / self.bin_width).astype(np.int64)
        over = idx >= len(self.counts)
        self.overflow += int(over.sum())
        idx = idx[~over]
        if idx.size < 256:  # a few values: no histogram-sized temporary
            np.add.at(self.counts, idx, 1)
        else:
            self.counts += np.bincount(idx, minlength=len(self.counts))

    def merge(self, other: RunningStats) -> None:
        """Add another's values (the same bins)."""
        if other.bin_width != self.bin_width or len(other.counts) != len(self.counts):
            raise ValueError("RunningStats.merge needs the same bins")
        self.counts += other.counts
        self.overflow += other.overflow
        self.count += other.count
        self.total += other.total

    @property
    def mean(self) -> float:
        return self.total / self.count if self.count else math.nan

    def _value_at(self, rank: int, cumulative: np.ndarray) -> float:
        i = int(np.searchsorted(cumulative, rank, side="right"))
        return self.top if i >= len(self.counts) else (i + 0.5) * self.bin_width

    @property
    def median(self) -> float:
        """The median, within half a bin of the exact one (see the class); NaN when empty."""
        if not self.count:
            return math.nan
        cumulative = np.cumsum(self.counts)
        lo = self._value_at((self.count - 1) // 2, cumulative)
        hi = self._value_at(self.count // 2, cumulative)
        return 0.5 * (lo + hi)

    @property
    def nbytes(self) -> int:
        """Memory held by the histogram (fixed)."""
        return int(self.counts.nbytes)
