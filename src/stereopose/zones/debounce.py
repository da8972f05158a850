"""One debouncer for fences, behaviour and tickets: a raw condition turns its state on once it
has held for `on_s` and off once it has been false for `off_s`, so that a detection flickering
for a frame neither opens nor closes anything. Times are compared with TIME_EPS of slack (frame
times are sums of float steps, and a wait of exactly `on_s` counts as done).

`Latch` is one condition (a person's behaviour rule, a ticket's supervisor absent or worker
alone); `Debounced` holds many at once in arrays (people x zones, for the fences).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

TIME_EPS = 1e-9  # seconds: times compared with this slack, everywhere


@dataclass
class Latch:
    """A debounced condition: on after `on_s` of raw true, off after `off_s` of raw false.
    since: when the raw value began to differ from the state; began: when the current on
    period's condition began."""

    state: bool = False
    since: float | None = None
    began: float | None = None
    onset: float = 0.0  # when the condition of the last change began

    def step(self, raw: bool, t: float, on_s: float, off_s: float) -> str | None:
        """Advance to time t with the raw condition: "rose", "fell" or None."""
        if raw == self.state:
            self.since = None
            return None
        if self.since is None:
            self.since = t
        if t - self.since < (off_s if self.state else on_s) - TIME_EPS:
            return None
        self.state, self.onset, self.since = raw, self.since, None
        if raw:
            self.began = self.onset
        return "rose" if raw else "fell"


class Debounced:
    """The Latch of many conditions at once (rows, e.g. people, x columns, e.g. zones), each
    column with its own on_s and off_s (Z,). since: when the raw value started to differ from
    the state (NaN: it does not); began: when the current on-period's condition began."""

    def __init__(self, on_s: np.ndarray, off_s: np.ndarray) -> None:
        self.on_s, self.off_s = on_s, off_s
        Z = on_s.shape[0]
        self.state = np.zeros((0, Z), dtype=bool)
        self.since = np.zeros((0, Z))
        self.began = np.zeros((0, Z))  # when the current on-period's raw condition began

    def add_rows(self, n: int) -> None:
        Z = self.on_s.shape[0]
        self.state = np.concatenate([self.state, np.zeros((n, Z), dtype=bool)])
        self.since = np.concatenate([self.since, np.full((n, Z), np.nan)])
        self.began = np.concatenate([self.began, np.full((n, Z), np.nan)])

    def keep(self, mask: np.ndarray) -> None:
        self.state, self.since, self.began = self.state[mask], self.since[mask], self.began[mask]

    def step(
        self, rows: np.ndarray, raw: np.ndarray, t: float
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """Advance `rows` with raw (n, Z) at time t; returns (rose, fell) (n, Z) flags and the
        onset times (n, Z) of the changes (None when nothing changed)."""
        state, since = self.state[rows], self.since[rows]
        differs = raw != state
        if not differs.any():  # steady: whatever was pending is off, nothing changes
            if (since == since).any():  # since == since: not NaN
                self.since[rows] = np.nan
            none = np.zeros_like(differs)
            return none, none, None
        since = np.where(differs, np.where(np.isnan(since), t, since), np.nan)
        elapsed = t - since
        wait = np.where(state, self.off_s, self.on_s)
        with np.errstate(invalid="ignore"):
            flip = differs & (elapsed >= wait - TIME_EPS)
        rose, fell = flip & raw, flip & ~raw
        onset = np.where(flip, since, np.nan)
        state = state ^ flip
        began = np.where(rose, since, self.began[rows])
        since = np.where(flip, np.nan, since)
        self.state[rows], self.since[rows], self.began[rows] = state, since, began
        return rose, fell, onset
