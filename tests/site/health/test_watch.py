"""Cameras watched: camera_down once after timeout_s of silence, camera_up when frames return;
on a stepped clock, and through a real SQLite event log."""

from __future__ import annotations

from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from stereopose.io.records import event_from_record, event_record
from stereopose.io.sinks.events import query_events
from stereopose.io.sinks.eventwriter import SqliteSink
from stereopose.site.health.watch import CameraWatch


def test_a_silent_camera_goes_down_once_and_comes_back_up() -> None:
    watch = CameraWatch(["a", "b"], timeout_s=5.0, start=0.0)
    events = []
    for step in range(200):  # 10 steps per second for 20 s; camera b silent from 3 s to 12 s
        t = step / 10
        watch.frame("a", t)
        if not 3.0 < t < 12.0:
            watch.frame("b", t)
        events += watch.poll(t, step)
    assert [(e.type, e.camera) for e in events] == [("camera_down", "b"), ("camera_up", "b")]
    down, up = events
    assert down.t == pytest.approx(8.0)  # 5 s after its last frame, at 3.0 s
    assert down.onset_t == pytest.approx(3.0)
    assert (down.kind, down.zone, down.person) == ("camera", "", -1)
    assert up.onset_t == pytest.approx(12.0)
    assert up.duration_s == pytest.approx(9.0)
    assert watch.state("a") == watch.state("b") == "up"


def test_a_camera_whose_stream_is_known_lost_is_down_at_the_next_poll() -> None:
    """A stream that ended or whose decoder died is down at once, not after timeout_s of
    silence; its next frame undoes the mark, and it is up again as after any loss."""
    watch = CameraWatch(["a", "b"], timeout_s=5.0, start=0.0)
    watch.frame("a", 1.0)
    watch.frame("b", 1.0)
    watch.lost("b")
    watch.lost("no such camera")  # not watched: nothing
    (down,) = watch.poll(1.1, 11)
    assert (down.type, down.camera, down.onset_t) == ("camera_down", "b", 1.0)
    assert watch.poll(1.2, 12) == []  # once
    watch.frame("b", 1.5)
    (up,) = watch.poll(1.6, 16)
    assert (up.type, up.camera) == ("camera_up", "b")
    watch.lost("b")
    watch.frame("b", 1.7)  # a frame after the mark: it was not lost after all
    assert watch.poll(1.8, 18) == [] and watch.state("b") == "up"


def test_a_camera_that_never_gives_a_frame_goes_down_from_the_start() -> None:
    watch = CameraWatch(["a"], timeout_s=2.0, start=100.0)
    assert watch.poll(101.9) == [] and watch.state("a") == "waiting"
    (down,) = watch.poll(102.0, 7)
    assert (down.type, down.onset_t, down.frame) == ("camera_down", 100.0, 7)
    assert watch.poll(500.0) == []  # once, however long it stays down
    assert watch.state("a") == "down" and watch.age("a", 500.0) is None


def test_unknown_camera_and_bad_timeout_are_refused() -> None:
    with pytest.raises(ValueError, match="timeout_s"):
        CameraWatch(["a"], timeout_s=0.0)
    with pytest.raises(KeyError, match="not watched"):
        CameraWatch(["a"], timeout_s=1.0).frame("zz", 0.0)


@settings(max_examples=200, deadline=None)
@given(
    st.lists(
        st.tuples(st.floats(0.0, 3.0), st.booleans()),  # (time step, whether a frame came)
        max_size=60,
    ),
    st.floats(0.5, 4.0),
)
def test_events_alternate_down_up_and_down_only_after_the_timeout(steps, timeout_s) -> None:
    watch = CameraWatch(["c"], timeout_s=timeout_s)
    t, last, events = 0.0, 0.0, []
    for dt, came in steps:
        t += dt
        if came:
            watch.frame("c", t)
            last = t
        for e in watch.poll(t):
            events.append(e)
            if e.type == "camera_down":
                assert t - e.onset_t >= timeout_s and e.onset_t == last
    types = [e.type for e in events]
    assert types == ["camera_down", "camera_up"] * (len(types) // 2) + (
        ["camera_down"] if len(types) % 2 else []
    )


def test_camera_events_survive_the_event_log_and_json(tmp_path: Path) -> None:
    watch = CameraWatch(["cam01"], timeout_s=1.0)
    events = watch.poll(1.5, 3)
    watch.frame("cam01", 2.0)
    events += watch.poll(2.1, 4)
    sink = SqliteSink(tmp_path / "events.sqlite")
    sink.write_events(events)
    sink.close()
    rows = query_events(tmp_path / "events.sqlite")
    assert [event_from_record(r) for r in rows] == events
    assert [event_from_record(event_record(e)) for e in events] == events
    assert rows[0]["camera"] == "cam01" and event_record(events[1])["camera"] == "cam01"


def test_overdue_names_what_poll_would_take_down_and_a_shift_gives_a_stall_back() -> None:
    watch = CameraWatch(["a", "b", "c"], timeout_s=2.0, start=0.0)
    watch.frame("a", 1.0)
    watch.frame("b", 1.5)
    assert watch.overdue(2.9) == ["c"]  # never delivered: counted from the start
    assert watch.overdue(3.6) == ["a", "b", "c"] and watch.up() == ["a", "b", "c"]
    watch.shift(3.0)  # a stall of 3 s that ended: not their silence
    assert watch.overdue(3.6) == [] and watch.poll(3.6) == []
    assert [(e.type, e.camera) for e in watch.poll(5.0)] == [("camera_down", "c")]
    assert watch.up() == ["a", "b"]
