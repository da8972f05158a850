"""The metrics' help says what they count: stereopose_events_total counts every event the
service raises (zone, behaviour, camera, calibration, service), not only zone events."""

from __future__ import annotations

from stereopose.site.health.metrics import exposition, make_registry
from stereopose.site.health.stall import StallWatch
from stereopose.site.health.state import ServiceState
from stereopose.site.health.watch import CameraWatch


def test_the_events_counter_counts_and_says_every_kind_of_event():
    state = ServiceState(["cam"])
    stall = StallWatch(timeout_s=1.0)
    stall.beat(0.0)
    stall.beat(5.0)
    stall.resume(5.1)
    state.on_events([*CameraWatch(["cam"], timeout_s=1.0).poll(2.0), *stall.events()])
    text = exposition(make_registry(state)).decode()
    (help_line,) = [ln for ln in text.splitlines() if ln.startswith("# HELP stereopose_events")]
    assert "camera" in help_line and "service" in help_line
    assert not help_line.split(" ", 3)[3].startswith("Zone events")
    assert 'stereopose_events_total{type="camera_down"} 1.0' in text
    assert 'stereopose_events_total{type="service_stalled"} 1.0' in text
