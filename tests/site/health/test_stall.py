"""StallWatch: a stall of the whole service, seen from the loop's beat or from every camera
late at once; one service_stalled and one service_resumed; its length but KEPT_S held out of
the people's time; on a clock the test steps."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from stereopose.io.records import event_from_record, event_record
from stereopose.site.eventlog import level
from stereopose.site.health.stall import KEPT_S, StallWatch


def test_a_loop_that_did_not_run_past_the_timeout_is_one_stall() -> None:
    stall = StallWatch(timeout_s=2.0)
    for i in range(20):  # the loop beats 10 times a second
        assert not stall.beat(i / 10, i)
    assert stall.events() == [] and not stall.stalled
    assert stall.beat(1.9 + 7.0, 20)  # paused for 7 s
    assert stall.stalled and not stall.beat(9.0, 21)  # one stall, however many beats
    assert stall.resume(9.05, 9.1) == pytest.approx(7.15)
    stalled, resumed = stall.events()
    assert (stalled.type, stalled.kind, stalled.zone, stalled.person) == (
        "service_stalled",
        "service",
        "",
        -1,
    )
    assert stalled.onset_t == pytest.approx(1.9) and stalled.t == pytest.approx(8.9)
    assert stalled.duration_s == pytest.approx(7.0)
    assert resumed.type == "service_resumed" and resumed.duration_s == pytest.approx(7.15)
    assert stall.held_s == pytest.approx(7.15 - KEPT_S)
    assert stall.resume(10.0) is None and stall.events() == []  # nothing in progress


def test_a_gap_within_the_timeout_is_no_stall() -> None:
    stall = StallWatch(timeout_s=5.0)
    assert not any(stall.beat(t) for t in (0.0, 4.9, 9.8, 14.0))
    assert stall.events() == [] and stall.held_s == 0.0


def test_every_camera_late_is_one_stall_whose_held_time_is_bounded() -> None:
    stall = StallWatch(timeout_s=5.0, kept_s=0.5)
    assert stall.late(6.0, 1.0)
    assert not stall.late(7.0, 1.0)  # already stalled
    assert stall.resume(12.0, most=3.0) == pytest.approx(11.0)
    assert stall.held_s == pytest.approx(3.0)  # at most `most`
    assert [e.type for e in stall.events()] == ["service_stalled", "service_resumed"]


def test_service_events_are_alarms_and_survive_json() -> None:
    stall = StallWatch(timeout_s=1.0)
    stall.beat(0.0)
    stall.beat(3.0, 7)
    stall.resume(3.1)
    events = stall.events()
    assert [event_from_record(event_record(e)) for e in events] == events
    assert level("service", "service_stalled") == "alarm"
    assert level("service", "service_resumed") == "info"


def test_bad_arguments_are_refused() -> None:
    with pytest.raises(ValueError, match="timeout_s"):
        StallWatch(timeout_s=0.0)
    with pytest.raises(ValueError, match="kept_s"):
        StallWatch(timeout_s=1.0, kept_s=float("nan"))


@settings(max_examples=200, deadline=None)
@given(st.lists(st.floats(0.0, 4.0), min_size=1, max_size=40), st.floats(0.5, 3.0))
def test_stalls_and_resumes_alternate_and_the_people_time_never_goes_back(gaps, timeout_s):
    stall = StallWatch(timeout_s=timeout_s)
    t, people_t = 0.0, 0.0
    for gap in gaps:
        t += gap
        stall.beat(t)
        if stall.stalled:
            assert gap > timeout_s - 1e-9
            stall.resume(t + 0.01)
        assert t - stall.held_s >= people_t - 1e-9
        people_t = t - stall.held_s
    types = [e.type for e in stall.events()]
    assert types == ["service_stalled", "service_resumed"] * (len(types) // 2)
