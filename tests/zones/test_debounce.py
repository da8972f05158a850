"""One debouncer for fences, behaviour and tickets: a condition on after on_s of raw true and
off after off_s of raw false, the same in one Latch and in arrays of them."""

from __future__ import annotations

import numpy as np

from stereopose.zones.debounce import TIME_EPS, Debounced, Latch

STEP = 0.1  # frame times as sums of float steps, as the frame loop makes them


def test_a_flicker_shorter_than_the_wait_changes_nothing_and_a_wait_of_exactly_on_s_counts():
    latch, t, out = Latch(), 0.0, []
    for raw in [True, False, True, True, True, True, False, False, True, False, False, False]:
        out.append(latch.step(raw, t, on_s=0.3, off_s=0.2))
        t += STEP
    # on at the fourth frame of raw true (0.3 s after it began, as float sums make it); a
    # frame of raw false does not turn it off, two frames (0.2 s) do
    assert out == [None, None, None, None, None, "rose", None, None, None, None, None, "fell"]
    assert not latch.state


def test_the_onset_of_a_change_is_when_its_condition_began():
    latch = Latch()
    times = np.cumsum([STEP] * 10) - STEP
    changes = [latch.step(True, float(t), 0.25, 0.0) for t in times[:4]]
    assert changes == [None, None, None, "rose"]
    assert abs(latch.onset - 0.0) < TIME_EPS and latch.began == latch.onset
    assert latch.step(False, float(times[4]), 0.25, 0.0) == "fell"  # off_s 0: at once
    assert abs(latch.onset - times[4]) < TIME_EPS


def test_arrays_of_conditions_debounce_as_one_latch_each():
    rng = np.random.default_rng(3)
    on_s, off_s = np.array([0.0, 0.2, 0.5]), np.array([0.3, 0.0, 0.1])
    many = Debounced(on_s, off_s)
    many.add_rows(4)
    latches = [[Latch() for _ in range(3)] for _ in range(4)]
    rows = np.arange(4)
    t = 0.0
    for _ in range(200):
        raw = rng.random((4, 3)) < 0.6
        rose, fell, onset = many.step(rows, raw, t)
        for r in range(4):
            for z in range(3):
                got = latches[r][z].step(bool(raw[r, z]), t, float(on_s[z]), float(off_s[z]))
                assert (got == "rose") == bool(rose[r, z]), (t, r, z)
                assert (got == "fell") == bool(fell[r, z]), (t, r, z)
                if got is not None:
                    assert onset is not None and abs(onset[r, z] - latches[r][z].onset) < 1e-12
                assert bool(many.state[r, z]) == latches[r][z].state
        t += STEP
