"""Counts over a recent window of time, in fixed buckets: rates that follow what happens now,
not totals since the start, in memory that never grows.

    frames = RateWindow(span_s=60.0, buckets=12)
    frames.add(now)                       # one frame at time now (seconds, any one clock)
    frames.total(now), frames.covered(now), frames.rate(now)

A bucket holds `span_s / buckets` seconds; `total(now)` counts the buckets within the last
`span_s` (so the window is between span_s - width and span_s long), `covered(now)` is how much
of it has passed since the first count, and `rate` divides the one by the other.

`CameraRates` judges one camera of the service over such windows: processed under SLOW_SHARE of
its nominal rate, or more than DROP_SHARE of its frames dropped (beyond those a lower nominal
rate passes over on purpose), once it has delivered for JUDGED_AFTER_S.
"""

from __future__ import annotations

import math

__all__ = ["CameraRates", "RateWindow"]

RATE_WINDOW_S = 60.0  # a camera's processed rate and drops are judged over this long
RATE_BUCKETS = 12
SLOW_SHARE = 0.5  # processed under this share of the nominal rate: degraded
DROP_SHARE = 0.5  # more than this share of a camera's frames dropped: degraded
JUDGED_AFTER_S = 10.0  # a camera's rates are judged once it has delivered this long


class RateWindow:
    """See the module. span_s (> 0): the window; buckets (>= 1): how finely it moves."""

    def __init__(self, span_s: float = 60.0, buckets: int = 12) -> None:
        if not (span_s > 0 and math.isfinite(span_s)):
            raise ValueError(f"span_s must be a positive number of seconds, got {span_s}")
        if buckets < 1:
            raise ValueError(f"a window needs at least one bucket, got {buckets}")
        self.span_s, self.width = float(span_s), float(span_s) / buckets
        self._counts = [0] * buckets
        self._slots: list[int | None] = [None] * buckets  # the bucket number each slot holds
        self.first_t: float | None = None

    def _slot(self, t: float) -> int:
        return math.floor(t / self.width)

    def add(self, t: float, n: int = 1) -> None:
        """n counts at time t (a time before the window's oldest bucket is counted in it)."""
        if n <= 0 or not math.isfinite(t):
            return
        if self.first_t is None or t < self.first_t:
            self.first_t = t
        number = self._slot(t)
        i = number % len(self._counts)
        if self._slots[i] != number:
            slot = self._slots[i]
            if slot is not None and slot > number:  # older than the window
                return
            self._slots[i], self._counts[i] = number, 0
        self._counts[i] += n

    def total(self, now: float) -> int:
        """The counts within the window ending at now."""
        newest = self._slot(now)
        oldest = newest - len(self._counts) + 1
        return sum(
            c
            for c, s in zip(self._counts, self._slots, strict=True)
            if s is not None and oldest <= s <= newest
        )

    def covered(self, now: float) -> float:
        """Seconds of the window that have passed since the first count (0 before it)."""
        if self.first_t is None:
            return 0.0
        window = now - (self._slot(now) - len(self._counts) + 1) * self.width
        return max(0.0, min(window, now - self.first_t))

    def rate(self, now: float) -> float | None:
        """Counts per second over the window (None before any time has passed)."""
        covered = self.covered(now)
        return self.total(now) / covered if covered > 0 else None


class CameraRates:
    """One camera's frames processed and dropped over the last RATE_WINDOW_S. nominal_fps: the
    rate it should be processed at (None: not judged on its rate); kept_share: of its own
    frames, the share that rate takes (a lower detect_fps passes over the others)."""

    def __init__(self) -> None:
        self.processed = RateWindow(RATE_WINDOW_S, RATE_BUCKETS)
        self.drops = RateWindow(RATE_WINDOW_S, RATE_BUCKETS)
        self.nominal_fps: float | None = None
        self.kept_share = 1.0

    def set_nominal(self, nominal_fps: float | None, source_fps: float | None) -> None:
        self.nominal_fps = nominal_fps or None
        own = source_fps or None
        self.kept_share = min(1.0, nominal_fps / own) if nominal_fps and own else 1.0

    def judge(self, now: float) -> tuple[float | None, float | None, str | None]:
        """(processed fps, share of frames dropped, why it is processed badly), each None
        until the camera has delivered for JUDGED_AFTER_S (the why: also when it is not)."""
        if self.processed.covered(now) < JUDGED_AFTER_S:
            return None, None, None
        processed = self.processed.rate(now)
        kept, dropped = self.processed.total(now), self.drops.total(now)
        share = dropped / (kept + dropped) if kept + dropped else 0.0
        nominal = self.nominal_fps
        if processed is not None and nominal and processed < SLOW_SHARE * nominal:
            why = (
                f"processed at {processed:.2g} frames/s, under {SLOW_SHARE:.0%} of its "
                f"nominal {nominal:g}/s over the last {RATE_WINDOW_S:g} s"
            )
            return processed, share, why
        # the share beyond what the nominal rate passes over on purpose
        beyond = 1.0 - (1.0 - share) / self.kept_share if self.kept_share > 0 else 0.0
        if beyond > DROP_SHARE:
            return (
                processed,
                share,
                f"{share:.0%} of its frames dropped over the last {RATE_WINDOW_S:g} s",
            )
        return processed, share, None
