"""The MQTT sink against a real mosquitto: events, retained zone occupancy, rate-limited
people, availability and its last will, a broker away at start or restarted, login, TLS."""

from __future__ import annotations

import dataclasses
import json
import logging
import math
import os
import signal
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from brokers import Broker, Subscriber, free_port, make_certificate, require_mosquitto
from stereopose.errors import ConfigError
from stereopose.io.sinks import FrameResult
from stereopose.io.sinks.events import JsonlSink
from stereopose.io.sinks.mqtt import MqttSettings, MqttSink, topic_name, topic_part
from stereopose.types import Event, People3D
from waiting import wait_until

FPS = 25.0
SITE = "north/yard"  # a '/' inside: one topic level all the same
BASE = "stereopose/north%2Fyard"


@pytest.fixture
def broker(tmp_path: Path):
    b = Broker(tmp_path / "broker").start()
    yield b
    b.stop()


@pytest.fixture
def closing():
    """Closes the sinks and subscribers a test opens, also when it fails."""
    opened: list = []
    yield opened.append
    for thing in reversed(opened):
        thing.close()


def settings(port: int, **kw) -> MqttSettings:
    base = dict(
        host="127.0.0.1",
        port=port,
        site=SITE,
        reconnect_min_s=0.05,
        reconnect_max_s=0.2,
        close_timeout_s=3.0,
    )
    return MqttSettings(**{**base, **kw})


def event(k: int, person: int = 1, zone: str = "panel", type: str = "enter") -> Event:
    return Event(
        t=k / FPS,
        frame=k,
        person=person,
        zone=zone,
        kind="energized",
        type=type,
        onset_t=(k - 2) / FPS,
        joint="right_wrist",
        position=(1.0, 2.0),
    )


def people(frame: int, ids: list[int]) -> People3D:
    P = len(ids)
    J = np.zeros((P, 17, 3))
    J[..., 0] = np.arange(P)[:, None] + 0.5
    J[:, 5, 1], J[:, 6, 1] = 0.2, -0.2  # shoulders: facing +x
    return People3D(
        frame,
        J,
        np.ones((P, 17)),
        np.array(ids),
        np.full((P, 17), np.nan),
        np.full((P, 17), 2),
        np.full((P, 1), -1),
    )


def frame(k: int, ids: list[int] = (), events: list[Event] = ()) -> FrameResult:
    return FrameResult(k, k / FPS, {}, people(k, list(ids)), list(events))


def published(sink: MqttSink, kind: str) -> int:
    return sink.figures()[kind]["published"]


# --- settings and topic levels, no broker needed ---


@pytest.mark.parametrize(
    ("change", "key"),
    [
        ({"host": ""}, "mqtt.host"),
        ({"host": "  "}, "mqtt.host"),
        ({"port": 0}, "mqtt.port"),
        ({"port": 65536}, "mqtt.port"),
        ({"port": True}, "mqtt.port"),
        ({"port": "1883"}, "mqtt.port"),
        ({"site": ""}, "mqtt.site"),
        ({"topic_prefix": ""}, "mqtt.topic_prefix"),
        ({"topic_prefix": "a//b"}, "mqtt.topic_prefix"),
        ({"topic_prefix": "a/+"}, "mqtt.topic_prefix"),
        ({"topic_prefix": "#"}, "mqtt.topic_prefix"),
        ({"topic_prefix": "$SYS"}, "mqtt.topic_prefix"),
        ({"topic_prefix": "a\x00b"}, "mqtt.topic_prefix"),
        ({"queue_size": 0}, "mqtt.queue_size"),
        ({"keepalive_s": 0}, "mqtt.keepalive_s"),
        ({"people_hz": -1.0}, "mqtt.people_hz"),
        ({"people_hz": math.nan}, "mqtt.people_hz"),
        ({"reconnect_min_s": 0.0}, "mqtt.reconnect_min_s"),
        ({"reconnect_min_s": 5.0, "reconnect_max_s": 1.0}, "mqtt.reconnect_min_s"),
        ({"tls": True, "ca_file": Path("/nonexistent/ca.pem")}, "mqtt.ca_file"),
        ({"ca_file": Path(__file__)}, "mqtt.ca_file"),
        ({"password": "secret"}, "mqtt.password"),
    ],
)
def test_bad_settings_name_the_key(change: dict, key: str) -> None:
    with pytest.raises(ConfigError, match=rf"^{key}: "):
        MqttSettings(**{"host": "broker", "site": "yard", **change})


def test_a_ca_file_that_is_no_certificate(tmp_path: Path) -> None:
    (tmp_path / "ca.pem").write_text("not a certificate\n")
    with pytest.raises(ConfigError, match=r"^mqtt\.ca_file: cannot load CAs from .*ca\.pem"):
        MqttSink(settings(free_port(), tls=True, ca_file=tmp_path / "ca.pem"))


def test_the_password_is_never_shown() -> None:
    s = settings(1883, username="ops", password="hunter2", topic_prefix="plant/stereopose")
    assert "hunter2" not in repr(s) and "ops" in repr(s)


@given(st.text(st.characters(codec=None, exclude_categories=())))
def test_topic_levels_are_safe_and_reversible(name: str) -> None:
    part = topic_part(name)
    assert part and not set(part) & set("/+#\x00")
    assert all(ord(c) >= 0x20 and not 0x7F <= ord(c) <= 0x9F for c in part)
    part.encode("utf-8")  # valid UTF-8: no lone surrogate left
    assert topic_name(part) == name  # one-to-one: two zones never share a topic


def test_topic_levels_keep_plain_names() -> None:
    assert topic_part("energized_panel_A") == "energized_panel_A"
    assert topic_part("Schaltfeld Ä") == "Schaltfeld Ä"
    assert topic_part("a/b+c#d%") == "a%2Fb%2Bc%23d%25"


# --- against mosquitto ---


def test_events_arrive_in_order_as_the_json_lines(broker, closing, tmp_path: Path) -> None:
    sub = Subscriber(broker.port, f"{BASE}/events")
    closing(sub)
    sink = MqttSink(settings(broker.port))
    jsonl = JsonlSink(tmp_path / "events.jsonl")
    frames = [
        frame(k, [1], [event(k, person=k % 3, type=("enter", "exit")[k % 2])]) for k in range(40)
    ]
    frames.append(frame(40, [1], [event(40, zone="bench"), event(40, zone="panel", person=7)]))
    for f in frames:
        sink.write(f)
        jsonl.write(f)
    jsonl.close()
    lines = (tmp_path / "events.jsonl").read_text().splitlines()
    wait_until(lambda: len(sub.on(f"{BASE}/events")) >= len(lines), "every event")
    assert sub.on(f"{BASE}/events") == lines
    sink.close()
    assert sink.figures()["events"] == {"published": 42, "queued": 0, "dropped": 0, "failed": 0}
    assert sink.close() == []  # once


def test_zone_occupancy_is_retained(broker, closing) -> None:
    names = ["panel A/1", "bench+#", "tab\there", "nul\x00", ""]
    sink = MqttSink(settings(broker.port), zone_names=names)
    closing(sink)
    for k, (person, zone, kind) in enumerate(
        [
            (1, "panel A/1", "enter"),
            (2, "panel A/1", "enter"),
            (1, "panel A/1", "exit"),
            (3, "bench+#", "enter"),
            (3, "bench+#", "approach"),
            (4, "ladder", "enter"),
        ]
    ):
        sink.write(frame(k, [person], [event(k, person=person, zone=zone, type=kind)]))
    wait_until(lambda: sink.figures()["zones"]["queued"] == 0, "the zone states sent")
    late = Subscriber(broker.port, f"{BASE}/zones/+")  # after the fact: retained states
    closing(late)
    wait_until(lambda: len({m.topic for m in late.messages}) == len(names) + 1, "all zones")
    state = {}
    for m in late.messages:
        assert m.retain
        body = json.loads(m.payload)
        assert topic_name(m.topic.rsplit("/", 1)[1]) == body["zone"]
        state[body["zone"]] = body["people"]
    assert state == {
        "panel A/1": [2],
        "bench+#": [3],
        "tab\there": [],
        "nul\x00": [],
        "": [],
        "ladder": [4],
    }


def test_a_zones_state_from_its_breakers_is_in_its_retained_message(broker, closing) -> None:
    sink = MqttSink(settings(broker.port), zone_names=["bay2", "bench"])
    closing(sink)
    dead = dataclasses.replace(event(1, person=-1, zone="bay2", type="zone_dead"), source="rtu")
    sink.write(frame(1, [], [dead]))
    sink.write(frame(2, [3], [event(2, person=3, zone="bay2")]))
    wait_until(lambda: sink.figures()["zones"]["queued"] == 0, "the zone states sent")
    late = Subscriber(broker.port, f"{BASE}/zones/+")
    closing(late)
    wait_until(lambda: len({m.topic for m in late.messages}) == 2, "both zones")
    bodies = {json.loads(m.payload)["zone"]: json.loads(m.payload) for m in late.messages}
    assert bodies["bay2"]["power"] == "dead" and bodies["bay2"]["power_source"] == "rtu"
    assert bodies["bay2"]["people"] == [3]
    assert "power" not in bodies["bench"]  # no state source
    # switched off over MQTT (io.sinks.mqtt_commands): its retained state says so
    off = dataclasses.replace(
        event(3, person=-1, zone="bench", type="zone_disabled"), kind="service"
    )
    sink.write(frame(3, [], [off]))
    wait_until(
        lambda: any(json.loads(m.payload).get("enabled") is False for m in late.messages),
        "the zone's state switched off",
    )
    assert "enabled" not in bodies["bay2"]


def test_people_are_rate_limited_by_frame_time(broker, closing) -> None:
    sub = Subscriber(broker.port, f"{BASE}/people")
    closing(sub)
    sink = MqttSink(settings(broker.port, people_hz=5.0))
    closing(sink)
    for k in range(100):  # 4 s at 25 fps: an update every 5th frame
        sink.write(frame(k, [3, 8]))
    for k in range(100, 150):  # nobody: one update saying so, then silence
        sink.write(frame(k))
    wait_until(lambda: published(sink, "people") == 21, "21 people updates")
    wait_until(lambda: len(sub.on(f"{BASE}/people")) == 21, "21 received")
    got = [json.loads(p) for p in sub.on(f"{BASE}/people")]
    assert [g["frame"] for g in got] == [*range(0, 100, 5), 100]
    assert got[0]["t"] == 0.0 and got[1]["t"] == 0.2
    assert got[0]["people"] == [
        {"id": 3, "position": [0.5, 0.0], "heading_deg": 0.0},
        {"id": 8, "position": [1.5, 0.0], "heading_deg": 0.0},
    ]
    assert got[-1]["people"] == []


def test_people_carry_their_posture_where_the_behaviour_rules_give_one(broker, closing) -> None:
    from stereopose.behaviour.posture import Posture

    sub = Subscriber(broker.port, f"{BASE}/people")
    closing(sub)
    sink = MqttSink(settings(broker.port, people_hz=5.0))
    closing(sink)
    postures = {3: Posture("crouching", ("reaching",))}  # person 8: none this frame
    sink.write(FrameResult(0, 0.0, {}, people(0, [3, 8]), [], postures=postures))
    wait_until(lambda: len(sub.on(f"{BASE}/people")) == 1, "the update")
    got = json.loads(sub.on(f"{BASE}/people")[0])["people"]
    assert got[0] == {
        "id": 3,
        "position": [0.5, 0.0],
        "heading_deg": 0.0,
        "posture": "crouching",
        "flags": ["reaching"],
    }
    assert got[1] == {"id": 8, "position": [1.5, 0.0], "heading_deg": 0.0}


def test_available_online_then_offline_at_close(broker, closing) -> None:
    sub = Subscriber(broker.port, f"{BASE}/available")
    closing(sub)
    sink = MqttSink(settings(broker.port))
    wait_until(lambda: sub.on(f"{BASE}/available") == ["online"], "online")
    sink.close()
    wait_until(lambda: sub.on(f"{BASE}/available") == ["online", "offline"], "offline")
    late = Subscriber(broker.port, f"{BASE}/available")
    closing(late)
    wait_until(lambda: late.on(f"{BASE}/available") == ["offline"], "offline retained")


KILLED = """
import sys, time
from stereopose.io.sinks.mqtt import MqttSettings, MqttSink
sink = MqttSink(MqttSettings(host="127.0.0.1", port=int(sys.argv[1]), site=sys.argv[2]))
print("up", flush=True)
time.sleep(60)
"""


def test_offline_by_the_last_will_when_the_process_dies(broker, closing) -> None:
    sub = Subscriber(broker.port, f"{BASE}/available")
    closing(sub)
    proc = subprocess.Popen(
        [sys.executable, "-c", KILLED, str(broker.port), SITE], stdout=subprocess.PIPE, text=True
    )
    try:
        wait_until(lambda: sub.on(f"{BASE}/available") == ["online"], "online")
    finally:
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
    wait_until(lambda: sub.on(f"{BASE}/available") == ["online", "offline"], "the last will")


def test_broker_away_at_start_loses_nothing_within_the_bound(
    tmp_path: Path, closing, caplog
) -> None:
    broker = Broker(tmp_path / "broker").start()
    sub = Subscriber(broker.port, f"{BASE}/events", f"{BASE}/people", session="watcher")
    sub.close()  # its session (and what comes for it) stays with the broker
    broker.stop()
    try:
        sink = MqttSink(settings(broker.port, queue_size=10, people_hz=FPS))
        closing(sink)
        # 6 people updates, then 8 events: 14 for 10 places, the 4 oldest people updates go;
        # 3 more events: the last 2 people updates go, then the oldest event
        for k in range(6):
            sink.write(frame(k, [1]))
        for k in range(6, 17):
            sink.write_events([event(k)])
        c = sink.figures()
        assert c["people"]["dropped"] == 6 and c["events"]["dropped"] == 1
        assert c["events"]["queued"] == 10 and c["people"]["queued"] == 0
        dropping = [r for r in caplog.records if "dropping the oldest" in r.getMessage()]
        assert len(dropping) == 1  # once for the burst, not per message
        broker.start()
        sub = Subscriber(broker.port, f"{BASE}/events", f"{BASE}/people", session="watcher")
        closing(sub)
        wait_until(lambda: len(sub.on(f"{BASE}/events")) == 10, "the queued events")
        assert [json.loads(p)["frame"] for p in sub.on(f"{BASE}/events")] == list(range(7, 17))
        assert sub.on(f"{BASE}/people") == []
        wait_until(lambda: published(sink, "events") == 10, "the broker's acknowledgements")
        c = sink.figures()
        assert c["events"] == {"published": 10, "queued": 0, "dropped": 1, "failed": 0}
    finally:
        broker.stop()


def test_broker_restarted_mid_run(tmp_path: Path, closing, caplog) -> None:
    caplog.set_level(logging.INFO, logger="stereopose.io.sinks.mqtt")
    broker = Broker(tmp_path / "broker").start()
    try:
        sub = Subscriber(broker.port, f"{BASE}/events", f"{BASE}/available", session="w2")
        closing(sub)
        sink = MqttSink(settings(broker.port))
        closing(sink)
        wait_until(lambda: "online" in sub.on(f"{BASE}/available"), "online")
        for k in range(20):
            sink.write_events([event(k)])
        broker.restart()  # some of these on their way, some still queued
        for k in range(20, 40):
            sink.write_events([event(k)])
        wait_until(lambda: published(sink, "events") == 40, "the events after the restart")
        wait_until(
            lambda: len({json.loads(p)["frame"] for p in sub.on(f"{BASE}/events")}) == 40,
            "every event received",
        )
        frames = [json.loads(p)["frame"] for p in sub.on(f"{BASE}/events")]
        assert list(dict.fromkeys(frames)) == list(range(40))  # at least once, in order
        assert sub.on(f"{BASE}/available").count("online") >= 2  # announced again
        assert "connection lost" in caplog.text and "connected; " in caplog.text
    finally:
        broker.stop()


def test_login_right_and_wrong(tmp_path: Path, closing, caplog) -> None:
    broker = Broker(tmp_path / "broker", users={"ops": "s3cret-pw"}).start()
    try:
        sub = Subscriber(broker.port, f"{BASE}/events", username="ops", password="s3cret-pw")
        closing(sub)
        good = MqttSink(settings(broker.port, username="ops", password="s3cret-pw"))
        closing(good)
        good.write(frame(0, [1], [event(0)]))
        wait_until(lambda: len(sub.on(f"{BASE}/events")) == 1, "the event")
        bad = MqttSink(
            settings(broker.port, username="ops", password="wrong-pw", close_timeout_s=0.2)
        )
        wait_until(lambda: bad.refused >= 2, "two refusals (it retries)")
        for k in range(5):  # the frame loop goes on
            bad.write(frame(k, [1], [event(k)]))
        bad.close()
        assert bad.figures()["events"]["queued"] == 5 and bad.figures()["events"]["published"] == 0
        refusals = [r for r in caplog.records if "refused the connection" in r.getMessage()]
        assert len(refusals) == 1 and refusals[0].levelno == logging.ERROR  # once, not per try
        assert "wrong-pw" not in caplog.text and "s3cret-pw" not in caplog.text
        assert len(sub.on(f"{BASE}/events")) == 1
    finally:
        broker.stop()


def test_tls_with_a_given_ca(tmp_path: Path, closing) -> None:
    require_mosquitto()
    cert, key = make_certificate(tmp_path)
    broker = Broker(tmp_path / "broker", tls=(cert, key)).start()
    try:
        sink = MqttSink(settings(broker.port, host="localhost", tls=True, ca_file=cert))
        closing(sink)
        sink.write_events([event(0)])
        wait_until(lambda: published(sink, "events") == 1, "the event over TLS")
    finally:
        broker.stop()


def test_close_is_bounded_with_no_broker(closing) -> None:
    sink = MqttSink(settings(free_port(), close_timeout_s=0.1))
    sink.write(frame(0, [1], [event(0)]))
    sink.close()
    assert sink.figures()["events"]["queued"] == 1


def test_a_hung_broker_blocks_neither_writes_nor_close(broker, closing) -> None:
    sink = MqttSink(settings(broker.port, close_timeout_s=0.3))
    closing(sink)
    sub = Subscriber(broker.port, f"{BASE}/available")
    closing(sub)
    wait_until(lambda: sub.on(f"{BASE}/available") == ["online"], "online")
    broker.proc.send_signal(signal.SIGSTOP)  # takes bytes, answers nothing
    try:
        for k in range(60):
            sink.write(frame(k, [1], [event(k)]))
        finished = threading.Thread(target=sink.close, daemon=True)
        finished.start()
        finished.join(timeout=10.0)
        assert not finished.is_alive(), "close blocked on a hung broker"
        c = sink.figures()["events"]
        assert c["published"] + c["queued"] == 60 and c["queued"] >= 40  # at most 20 in flight
    finally:
        broker.proc.send_signal(signal.SIGCONT)


def test_a_message_published_as_the_link_drops_is_counted_when_resent(closing) -> None:
    """paho keeps MQTT_ERR_NO_CONN in the info of a message published as the link went down,
    and raises on asking it later, although it resends the message on reconnecting: the sink
    counts it as waiting, then as published once paho says it went out."""
    import paho.mqtt.client as paho

    sink = MqttSink(settings(free_port()))  # no broker: nothing else is in flight
    closing(sink)
    info = paho.MQTTMessageInfo(7)
    info.rc = paho.MQTT_ERR_NO_CONN
    with pytest.raises(RuntimeError):
        info.is_published()
    sink._inflight.append(("events", info))
    assert sink.figures()["events"]["queued"] == 1  # waiting, and no exception
    sink._on_publish(None, None, 7)  # paho resent it after reconnecting
    assert published(sink, "events") == 1 and sink.figures()["events"]["queued"] == 0


def test_the_site_is_retained_and_a_removed_zone_is_cleared(broker, closing) -> None:
    """`site` retained with the running site's version and zones; at a change, a new zone's
    state is published (empty) and a removed one's retained state cleared, so a late
    subscriber sees the new site's zones only."""
    sink = MqttSink(settings(broker.port), zone_names=["bay1", "bay2"])
    closing(sink)
    sink.set_site("v1", ["bay1", "bay2"], 1.8e9)
    sink.write(frame(1, [3], [event(1, person=3, zone="bay2")]))
    wait_until(lambda: sink.figures()["zones"]["queued"] == 0, "the zone states sent")
    sink.set_site("v2", ["bay1", "bay3"], 1.8e9 + 60)
    wait_until(lambda: sink.figures()["zones"]["queued"] == 0, "the change sent")
    late = Subscriber(broker.port, f"{BASE}/site", f"{BASE}/zones/+")
    closing(late)
    wait_until(lambda: late.on(f"{BASE}/site"), "the retained site")
    wait_until(lambda: len({m.topic for m in late.messages}) == 3, "the site and two zones")
    (site,) = late.on(f"{BASE}/site")
    assert json.loads(site) == {"version": "v2", "zones": ["bay1", "bay3"], "t": 1.8e9 + 60}
    assert {m.topic for m in late.messages} == {
        f"{BASE}/site",
        f"{BASE}/zones/bay1",
        f"{BASE}/zones/bay3",
    }
    assert all(m.retain for m in late.messages)


def test_what_warns_on_site_is_retained_its_newest_only(broker, closing) -> None:
    """`warnings` retained (onsite.warner's document): a subscriber follows each change, and
    one that comes later gets the newest, retained."""
    sink = MqttSink(settings(broker.port), zone_names=["busbar"])
    closing(sink)
    now = Subscriber(broker.port, f"{BASE}/warnings")
    closing(now)
    first = {"warnings": [{"zone": "busbar", "person": 1, "kind": "approach"}], "t": 1.0}
    sink.set_warnings(first)
    wait_until(lambda: now.on(f"{BASE}/warnings"), "the warnings")
    sink.set_warnings({"warnings": [], "t": 2.0})
    wait_until(lambda: len(now.on(f"{BASE}/warnings")) == 2, "the change")
    assert json.loads(now.on(f"{BASE}/warnings")[0]) == first
    late = Subscriber(broker.port, f"{BASE}/warnings")
    closing(late)
    wait_until(lambda: late.on(f"{BASE}/warnings"), "the retained warnings")
    assert json.loads(late.on(f"{BASE}/warnings")[-1]) == {"warnings": [], "t": 2.0}
    assert all(m.retain for m in late.messages)
