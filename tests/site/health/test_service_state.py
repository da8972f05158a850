"""ServiceState: cameras up and down by their timeouts, bounded memory, probes that fail,
and writers that never raise whatever the loop hands them."""

from __future__ import annotations

import math
import sys

import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from served import Clock, event, frame_result
from stereopose.site.health import state as state_mod
from stereopose.site.health.alarm_outputs import BACKLOG_S
from stereopose.site.health.state import FPS_WINDOW, MAX_NAMES, ServiceState


def test_a_camera_is_down_before_its_first_frame_and_after_its_timeout():
    clock = Clock()
    s = ServiceState(["cam_01", "cam_02"], camera_timeout_s=2.0, clock=clock)
    assert s.snapshot().status == "down"
    for _ in range(11):  # 10 frames a second for one second
        s.camera_frame("cam_01", clock.now)
        s.camera_frame("cam_02")  # arrived now
        clock.now += 0.1
    clock.now -= 0.1
    snap = s.snapshot()
    assert snap.status == "ok" and snap.problems == ()
    assert [c.state for c in snap.cameras] == ["up", "up"]
    assert snap.cameras[0].fps == pytest.approx(10.0)
    assert snap.cameras[0].last_frame_age_s == pytest.approx(0.0)
    s.camera_frame("cam_01", clock.now)
    clock.now += 2.5  # cam_02's last frame is 2.5 s old, cam_01's too: both down
    assert s.snapshot().status == "down"
    s.camera_frame("cam_01", clock.now)
    snap = s.snapshot()
    cams = {c.name: c for c in snap.cameras}
    assert cams["cam_01"].up and not cams["cam_02"].up
    assert cams["cam_02"].fps == 0.0 and cams["cam_02"].last_frame_age_s == pytest.approx(2.5)
    assert snap.status == "degraded" and snap.problems == ("camera cam_02 down",)


def test_each_camera_has_its_own_timeout():
    clock = Clock()
    s = ServiceState(camera_timeout_s=1.0, clock=clock)
    s.add_camera("slow", timeout_s=10.0)
    s.camera_frame("slow", clock.now)
    s.camera_frame("fast", clock.now)  # added on its first frame, with the default timeout
    clock.now += 5.0
    assert {c.name: c.up for c in s.snapshot().cameras} == {"slow": True, "fast": False}


def test_a_reconnect_is_down_until_the_next_frame():
    clock = Clock()
    s = ServiceState(["cam"], clock=clock)
    s.camera_frame("cam", clock.now)
    s.camera_reconnect("cam")
    s.camera_dropped("cam", 3)
    (cam,) = s.snapshot().cameras
    assert (cam.up, cam.reconnects, cam.dropped_frames) == (False, 1, 3)
    s.camera_frame("cam", clock.now)
    assert s.snapshot().cameras[0].up


def test_frames_people_stages_and_latency():
    clock = Clock()
    s = ServiceState(["cam"], clock=clock)
    s.on_frame(frame_result(1, 3), {"detect": 0.02, "3d": 0.004})
    clock.now += 0.5
    s.on_frame(frame_result(2, 1), {"detect": 0.03, "3d": 0.006}, t_arrival=clock.now - 0.2)
    snap = s.snapshot()
    assert (snap.frames, snap.people) == (2, 1)
    detect = snap.stages["detect"]
    assert detect.count == 2 and detect.sum_s == pytest.approx(0.05)
    assert detect.cumulative[-1] == 2 and detect.bounds[-1] == math.inf
    e2e = snap.end_to_end  # 0.024 (the sum of the stages), then 0.2 (since the arrival)
    assert e2e.count == 2 and e2e.sum_s == pytest.approx(0.224)
    below = dict(zip(e2e.bounds, e2e.cumulative, strict=True))
    assert below[0.025] == 1 and below[0.1] == 1 and below[0.25] == 2


def test_events_by_type():
    s = ServiceState()
    s.on_events([event("enter"), event("enter"), event("exit")])
    s.on_event(event("dwell"))
    assert s.snapshot().events == {"enter": 2, "exit": 1, "dwell": 1}


def test_a_queue_that_drops_degrades_for_a_while():
    clock = Clock()
    dropped = [0]
    s = ServiceState(["cam"], clock=clock)
    s.register_queue("mqtt", lambda: 7, lambda: dropped[0])
    s.camera_frame("cam", clock.now)
    assert s.snapshot().status == "ok"
    dropped[0] = 5
    snap = s.snapshot()
    assert snap.status == "degraded" and snap.problems == ("queue mqtt dropping",)
    assert (snap.queues[0].size, snap.queues[0].dropped) == (7, 5)
    clock.now += state_mod.DROP_WINDOW_S + 1
    s.camera_frame("cam", clock.now)
    assert s.snapshot().status == "ok"  # no drop since


def test_failing_probes_are_reported_never_raised(caplog):
    clock = Clock()
    s = ServiceState(["cam"], clock=clock)
    s.camera_frame("cam", clock.now)

    def broken() -> int:
        raise OSError("gone")

    s.register_queue("broken", broken)
    s.register_queue("wrong", lambda: "seven")  # type: ignore[arg-type, return-value]
    s.register_storage(lambda: {"clips": 10, "db": -1})
    snap = s.snapshot()
    assert [q.size for q in snap.queues] == [None, None]
    assert snap.storage == {"clips": 10}
    assert snap.status == "degraded"
    assert set(snap.problems) == {
        "queue broken: size unknown",
        "queue wrong: size unknown",
        "storage: some sizes unknown",
    }
    assert "gone" in caplog.text


def test_an_alarm_output_down_degrades_with_its_reason_until_it_recovers():
    clock = Clock()
    health = [(False, 17, "broker unreachable")]
    s = ServiceState(["cam"], clock=clock)
    s.register_output("mqtt", lambda: health[0])
    s.camera_frame("cam", clock.now)
    snap = s.snapshot()
    assert snap.status == "degraded"
    assert snap.problems == ("output mqtt failing: broker unreachable (17 waiting)",)
    (out,) = snap.outputs
    assert (out.name, out.state, out.waiting, out.reason) == (
        "mqtt",
        "down",
        17,
        "broker unreachable",
    )
    health[0] = (True, 0, None)
    snap = s.snapshot()
    assert snap.status == "ok" and snap.problems == ()
    assert (snap.outputs[0].state, snap.outputs[0].reason) == ("up", None)


def test_an_output_with_messages_waiting_at_every_read_for_a_while_is_falling_behind():
    clock = Clock()
    waiting = [3]
    s = ServiceState(["cam"], camera_timeout_s=3600, clock=clock)
    s.register_output("webhook", lambda: (True, waiting[0], None))
    s.camera_frame("cam", clock.now)
    assert s.snapshot().status == "ok"  # waiting now and then is how messages go out
    clock.now += BACKLOG_S / 2
    assert s.snapshot().status == "ok"
    clock.now += BACKLOG_S / 2
    waiting[0] = 40
    snap = s.snapshot()
    assert snap.status == "degraded"
    assert snap.problems == (f"output webhook falling behind: 40 waiting for {BACKLOG_S:.0f} s",)
    waiting[0] = 0  # one read with nothing waiting: it keeps up
    assert s.snapshot().status == "ok"
    waiting[0] = 2
    clock.now += BACKLOG_S - 1
    assert s.snapshot().status == "ok" and s.snapshot().outputs[0].backlog_s == 0.0


def test_an_output_probe_that_fails_or_answers_nonsense_is_down(caplog):
    clock = Clock()
    s = ServiceState(["cam"], clock=clock)
    s.camera_frame("cam", clock.now)

    def broken() -> tuple[bool, int, str | None]:
        raise RuntimeError("probe bug")

    s.register_output("broken", broken)
    s.register_output("truthy", lambda: (1, 0, None))  # type: ignore[arg-type, return-value]
    s.register_output("silent", lambda: (False, -1, None))
    snap = s.snapshot()
    assert [(o.name, o.up, o.waiting, o.reason) for o in snap.outputs] == [
        ("broken", False, None, "its health is unknown"),
        ("truthy", False, 0, "not delivering"),
        ("silent", False, None, "not delivering"),
    ]
    assert snap.status == "degraded" and len(snap.problems) == 3
    assert "probe bug" in caplog.text


def test_memory_is_bounded_however_long_it_runs():
    clock = Clock()
    s = ServiceState(clock=clock)
    for i in range(5 * FPS_WINDOW):
        s.camera_frame("cam", clock.now)
        s.on_frame(frame_result(i, 1), {"detect": 0.01})
        clock.now += 0.04
    assert len(s._cameras["cam"].arrivals) == FPS_WINDOW
    assert s.snapshot().cameras[0].fps == pytest.approx(25.0)
    size = sys.getsizeof(s._stages["detect"].counts)
    for i in range(2000):
        s.on_frame(frame_result(i, 1), {"detect": 0.01 * (i % 50)})
    assert sys.getsizeof(s._stages["detect"].counts) == size


def test_names_beyond_the_cap_are_not_reported(caplog):
    s = ServiceState()
    for i in range(MAX_NAMES + 10):
        s.camera_frame(f"cam_{i}")
        s.on_frame(frame_result(i, 0), {f"stage_{i}": 0.01})
        s.on_event(event(f"type_{i}"))
    snap = s.snapshot()
    assert len(snap.cameras) == len(snap.stages) == len(snap.events) == MAX_NAMES
    assert snap.frames == MAX_NAMES + 10
    assert caplog.text.count("not reported") == 3  # once per kind of name


values = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(),
    st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=3),
)


@settings(max_examples=150, deadline=None)
@example(arrivals=[10**400], timings={"x": 10**400}, t_arrival=-(10**400), dropped=10**400)
@given(
    arrivals=st.lists(values, max_size=6),
    timings=st.dictionaries(st.text(max_size=4), values, max_size=4),
    t_arrival=values,
    dropped=values,
)
def test_writers_never_raise_and_the_snapshot_stays_finite(arrivals, timings, t_arrival, dropped):
    clock = Clock()
    s = ServiceState(["cam"], clock=clock)
    for t in arrivals:
        s.camera_frame("cam", t)
    s.camera_dropped("cam", dropped)
    s.on_frame(frame_result(1, 2), timings, t_arrival)
    s.on_frame(object(), {}, None)  # not a frame result: counted, nobody in it
    snap = s.snapshot()
    (cam,) = snap.cameras
    assert math.isfinite(cam.fps) and cam.fps >= 0
    assert cam.last_frame_age_s is None or math.isfinite(cam.last_frame_age_s)
    assert cam.dropped_frames >= 0 and snap.frames == 2
    assert math.isfinite(snap.end_to_end.sum_s) and snap.end_to_end.count == 2
    for h in snap.stages.values():
        assert math.isfinite(h.sum_s) and h.cumulative[-1] == h.count == 1
    clock.now += 5.0 + 1e-6  # past the timeout, whatever times came (a future one is now)
    assert not s.snapshot().cameras[0].up


def test_an_arrival_on_another_clock_does_not_keep_a_camera_up():
    clock = Clock()
    s = ServiceState(["cam"], camera_timeout_s=1.0, clock=clock)
    s.camera_frame("cam", 1.7e9)  # wall-clock seconds, not the state's clock: taken as now
    clock.now += 1.5
    assert not s.snapshot().cameras[0].up


def test_bad_construction_arguments():
    with pytest.raises(ValueError, match="camera_timeout_s"):
        ServiceState(camera_timeout_s=0)
    with pytest.raises(ValueError, match="increasing"):
        ServiceState(latency_buckets_s=(0.1, 0.1))


def test_a_camera_processed_far_under_its_nominal_rate_degrades_with_the_reason():
    clock = Clock()
    s = ServiceState(camera_timeout_s=5.0, clock=clock)
    s.add_camera("fast", nominal_fps=10.0)
    s.add_camera("slow", timeout_s=4.0)
    s.camera_rate("slow", 25.0)  # known later (a stream once connected), its timeout kept
    for i in range(301):  # 30 s: "fast" at its 10 frames/s, "slow" at 2 of its 25
        s.camera_frame("fast", clock.now)
        if i % 5 == 0:
            s.camera_frame("slow", clock.now)
        clock.now += 0.1
    snap = s.snapshot()
    cams = {c.name: c for c in snap.cameras}
    assert cams["fast"].slow is None and cams["fast"].processed_fps == pytest.approx(10, rel=0.1)
    assert cams["slow"].processed_fps == pytest.approx(2.0, rel=0.1)
    assert (cams["slow"].nominal_fps, cams["slow"].timeout_s) == (25.0, 4.0)
    assert snap.status == "degraded"
    (problem,) = snap.problems
    assert problem.startswith("camera slow: processed at 2") and "nominal 25/s" in problem
    for _ in range(700):  # 70 s at its nominal rate: the window forgets the slow minute
        s.camera_frame("slow", clock.now)
        s.camera_frame("fast", clock.now)
        clock.now += 0.04
    assert s.snapshot().status == "ok"


def test_most_frames_dropped_degrades_beyond_those_a_lower_nominal_rate_passes_over():
    clock = Clock()
    s = ServiceState(camera_timeout_s=5.0, clock=clock)
    s.add_camera("paced", nominal_fps=5.0, source_fps=25.0)  # detect_fps 5 of a 25 fps stream
    s.add_camera("choked")  # a stream whose rate is not known
    for _ in range(150):  # 30 s, 5 steps a second; each camera's reader drops 4 of 5 frames
        s.camera_frame("paced", clock.now)
        s.camera_frame("choked", clock.now)
        s.camera_dropped("paced", 4)
        s.camera_dropped("choked", 4)
        clock.now += 0.2
    snap = s.snapshot()
    assert snap.problems == ("camera choked: 80% of its frames dropped over the last 60 s",)
    assert {c.name: c.dropped_share for c in snap.cameras} == pytest.approx(
        {"paced": 0.8, "choked": 0.8}
    )


def test_a_camera_is_not_judged_on_its_first_seconds_nor_without_a_nominal_rate():
    clock = Clock()
    s = ServiceState(camera_timeout_s=5.0, clock=clock)
    s.add_camera("new", nominal_fps=25.0)
    s.camera_frame("unknown", clock.now)  # no nominal rate: never judged slow
    for _ in range(5):  # 5 s at 1 frame/s: too soon to judge
        s.camera_frame("new", clock.now)
        s.camera_frame("unknown", clock.now)
        clock.now += 1.0
    assert s.snapshot().problems == ()


def test_a_stall_of_the_service_is_a_problem_while_it_lasts():
    clock = Clock()
    s = ServiceState(["cam"], clock=clock)
    s.camera_frame("cam", clock.now)
    s.service_stall("stalled since 12.0 s")
    assert s.snapshot().problems == ("service stalled since 12.0 s",)
    s.service_stall(None)
    assert s.snapshot().status == "ok"
