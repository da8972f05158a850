"""An admin's hand on the outputs on site (onsite.control): silences that end by themselves or
when lifted, tests, each an event at the next step; and the speakers' health_url checks
(onsite.speaker_health) against a real HTTP server."""

from __future__ import annotations

import http.server
import threading
from typing import ClassVar

import pytest

from stereopose.alarms.levels import WARNING, hazard_key, level
from stereopose.onsite.control import ControlError, Controls
from stereopose.onsite.settings import SpeakerSpec
from stereopose.onsite.speaker_health import SpeakerChecks
from waiting import wait_until


class Clock:
    def __init__(self) -> None:
        self.now = 1000.0

    def __call__(self) -> float:
        return self.now


def test_a_silence_lasts_its_time_and_each_act_is_an_event():
    clock = Clock()
    c = Controls(lambda: {"pa", "tower"}, clock=clock)
    s = c.silence("pa", 600, "  amplifier\nserviced ", by="alice")
    assert (s.until, s.reason, s.by) == (1600.0, "amplifier serviced", "alice")
    assert set(c.silenced()) == {"pa"}
    (e,) = c.take(5.0, 100)
    assert (e.type, e.kind, e.source, e.t, e.frame) == (
        "warning_output_silenced",
        "service",
        "pa",
        5.0,
        100,
    )
    assert e.result["reason"] == "amplifier serviced" and e.result["by"] == "alice"
    assert level(e.kind, e.type) == WARNING and hazard_key(e) == ("silenced", "pa")
    assert c.take(5.1, 101) == []  # taken once
    clock.now = 1600.0  # its time is up
    assert c.silenced() == {}
    (end,) = c.take(6.0, 120)
    assert end.type == "warning_output_unsilenced" and hazard_key(end) == ("silenced", "pa")
    assert end.result["ended_by"] == ""


def test_a_silence_lifted_by_an_admin_and_the_acts_refused():
    c = Controls(lambda: {"pa", "tower"})
    with pytest.raises(ControlError) as e:
        c.silence("nowhere", 60, "x", by="alice")
    assert e.value.status == 404 and "'nowhere'" in str(e.value)
    for seconds, reason in ((0, "x"), (25 * 3600, "x"), (60, "   "), (60, "x" * 501)):
        with pytest.raises(ControlError) as e:
            c.silence("pa", seconds, reason, by="alice")
        assert e.value.status == 400
    with pytest.raises(ControlError) as e:
        c.lift("pa", by="bob")
    assert e.value.status == 404
    c.silence("tower", 60, "crane lift nearby", by="alice")
    c.lift("tower", by="bob")
    assert c.silenced() == {}
    types = [(e.type, e.result.get("ended_by")) for e in c.take(1.0, 1)]
    assert types == [("warning_output_silenced", None), ("warning_output_unsilenced", "bob")]
    c.test("pa", by="bob")
    assert c.take_tests() == [("pa", "bob")] and c.take_tests() == []
    (t,) = c.take(2.0, 2)
    assert t.type == "warning_output_test" and t.result == {"by": "bob"}


def test_acts_waiting_for_a_step_are_bounded_and_counted():
    c = Controls(lambda: {"pa"})
    for _ in range(300):
        c.test("pa", by="alice")
    assert len(c.take(0.0, 0)) == 256 and c.dropped >= 44


class _Device(http.server.BaseHTTPRequestHandler):
    status = 200
    logins: ClassVar[list] = []

    def do_GET(self):
        type(self).logins.append(self.headers.get("Authorization"))
        self.send_response(type(self).status)
        self.end_headers()

    def log_message(self, *args):
        pass


def test_a_speakers_health_url_is_asked_and_its_changes_told():
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), _Device)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    told: list = []
    url = f"http://user:secret@127.0.0.1:{server.server_port}/status"
    specs = [
        SpeakerSpec("pa", "127.0.0.1", 5004, ("busbar",), health_url=url),
        SpeakerSpec("horn", "127.0.0.1", 5006, ("busbar",)),
    ]
    checks = SpeakerChecks(lambda *a: told.append(a), check_s=0.05, timeout_s=1.0)
    try:
        checks.watch(specs)
        assert checks.state("horn") == "not verifiable"
        wait_until(lambda: checks.state("pa") == "up", "asked")
        assert told == []  # up from the first answer: nothing to tell
        assert _Device.logins[0] == "Basic dXNlcjpzZWNyZXQ="  # user:secret
        _Device.status = 503
        wait_until(lambda: told, "down")
        assert told == [("pa", False, "answered HTTP 503")] and checks.state("pa") == "down"
        _Device.status = 200
        wait_until(lambda: len(told) == 2, "back")
        assert told[1] == ("pa", True, "") and checks.state("pa") == "up"
        server.shutdown()
        server.server_close()
        wait_until(lambda: len(told) == 3, "down again: nobody answers")
        assert told[2][:2] == ("pa", False) and "secret" not in told[2][2]
    finally:
        _Device.status = 200
        checks.close()
