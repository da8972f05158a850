"""Behaviour events through every event sink (JSON lines, SQLite, webhook, MQTT) and the
postures into the 3D poses, from the monitor stepping a synthetic scene."""

from __future__ import annotations

import json
import sqlite3
from pathlib import Path

import numpy as np
import pytest

import bodies as b
from brokers import Broker, Subscriber
from receivers import Receiver
from stereopose.behaviour import parse_rules
from stereopose.behaviour.rules import BehaviourMonitor
from stereopose.io.records import event_from_record
from stereopose.io.results import read_poses
from stereopose.io.sinks import FrameResult
from stereopose.io.sinks.clips import is_alarm
from stereopose.io.sinks.events import (
    JsonlSink,
    WebhookSink,
    describe,
    query_events,
    read_events,
)
from stereopose.io.sinks.eventwriter import SqliteSink
from stereopose.io.sinks.files import PosesSink
from stereopose.io.sinks.mqtt import MqttSettings, MqttSink
from stereopose.types import Event
from stereopose.viz.report_behaviour import behaviour_events_html, postures_html
from stereopose.zones import Zone
from waiting import wait_until

FPS = 25.0
PANEL = Zone(
    "panel", "energized", np.array([[0.0, 2.0], [0.6, 2.0], [0.6, 4.0], [0.0, 4.0]]), (0.0, 2.5)
)
RULES = [
    {"name": "man_down", "type": "person_down", "down_s": 2.0},
    {"name": "two_man", "type": "lone_worker", "zones": ["panel"], "lone_s": 1.0},
    {"name": "overhead", "type": "overreach", "max_height_m": 1.9},
]


def frames() -> list[FrameResult]:
    """Person 1 falls at 0.5 s by the panel and stays down; person 2, far away, reaches up
    from 1 s on. 5 s at 25 fps."""
    mon = BehaviourMonitor(parse_rules(RULES, "test", [PANEL]), [PANEL], FPS, 3.0)
    stand = b.standing(xy=(1.0, 3.0), heading=np.pi)
    reach = b.standing(xy=(6.0, 3.0), reach_right=1.0)
    idle = b.standing(xy=(6.0, 3.0))
    out = []
    for k in range(round(5 * FPS)):
        t = k / FPS
        a = min(1.0, max(0.0, (t - 0.5) / 0.6))
        bodies = {1: b.tipped(stand, np.pi, 0.5 * np.pi * a * a), 2: reach if t >= 1.0 else idle}
        people = b.people(k, bodies, t)
        events, postures = mon.step(t, k, people)
        out.append(FrameResult(k, t, {}, people, events, None, postures))
    return out


@pytest.fixture(scope="module")
def run() -> list[FrameResult]:
    return frames()


def all_events(run: list[FrameResult]) -> list[Event]:
    return [e for f in run for e in f.events]


def test_the_scene_raises_the_expected_events(run) -> None:
    got = sorted((e.type, e.person, e.rule) for e in all_events(run))
    assert got == [
        ("lone_worker", 1, "two_man"),
        ("overreach", 2, "overhead"),
        ("person_down", 1, "man_down"),
    ]
    assert all(is_alarm(e) for e in all_events(run))  # each starts an event clip
    line = describe(next(e for e in all_events(run) if e.type == "person_down"))
    assert "person_down" in line and "man_down" in line and "lying" in line


def test_behaviour_events_in_jsonl_and_sqlite(tmp_path: Path, run) -> None:
    sinks = [JsonlSink(tmp_path / "events.jsonl"), SqliteSink(tmp_path / "events.sqlite")]
    for f in run:
        for s in sinks:
            s.write(f)
    for s in sinks:
        s.close()
    events = all_events(run)
    lines = [json.loads(x) for x in (tmp_path / "events.jsonl").read_text().splitlines()]
    assert len(lines) == len(events)
    down = next(rec for rec in lines if rec["type"] == "person_down")
    assert down["rule"] == "man_down" and down["kind"] == "behaviour" and down["zone"] == ""
    assert down["posture"] == "lying" and down["speed_m_s"] > 1.0 and "duration_s" in down
    over = next(rec for rec in lines if rec["type"] == "overreach")
    assert over["joint"] == "right_wrist" and over["height_m"] > 1.9
    lone = next(rec for rec in lines if rec["type"] == "lone_worker")
    assert lone["zone"] == "panel" and "nearest_m" in lone
    assert read_events(tmp_path / "events.jsonl") == _rounded(events)
    rows = query_events(tmp_path / "events.sqlite")
    assert [r["rule"] for r in rows] == [e.rule for e in events]
    assert [event_from_record(r) for r in rows] == events  # full precision
    assert query_events(tmp_path / "events.sqlite", event_type="person_down")[0]["posture"] == (
        "lying"
    )


def _rounded(events: list[Event]) -> list[Event]:
    from stereopose.io.records import event_record

    return [event_from_record(json.loads(json.dumps(event_record(e)))) for e in events]


def test_an_event_log_of_an_earlier_version_gets_the_new_columns(tmp_path: Path, run) -> None:
    """A log made before behaviour events: its rows kept, behaviour events stored beside."""
    db_path = tmp_path / "old.sqlite"
    db = sqlite3.connect(db_path)
    db.executescript("""
        CREATE TABLE runs (id INTEGER PRIMARY KEY, started REAL NOT NULL, site TEXT,
                           source TEXT);
        CREATE TABLE events (id INTEGER PRIMARY KEY, run INTEGER NOT NULL, t REAL NOT NULL,
            frame INTEGER NOT NULL, person INTEGER NOT NULL, zone TEXT NOT NULL,
            kind TEXT NOT NULL, type TEXT NOT NULL, onset_t REAL, joint TEXT, distance_m REAL,
            duration_s REAL, x REAL, y REAL, allowed INTEGER NOT NULL DEFAULT 0,
            lost INTEGER NOT NULL DEFAULT 0);
        INSERT INTO runs(started) VALUES (1.0);
        INSERT INTO events(run, t, frame, person, zone, kind, type)
            VALUES (1, 0.5, 12, 4, 'panel', 'energized', 'enter');
    """)
    db.commit()
    db.close()
    rows = query_events(db_path)  # readable as it is
    assert rows[0]["type"] == "enter" and rows[0]["rule"] is None
    sink = SqliteSink(db_path)
    for f in run:
        sink.write(f)
    sink.close()
    rows = query_events(db_path)
    assert rows[0]["type"] == "enter"
    assert [r["rule"] for r in rows[1:]] == [e.rule for e in all_events(run)]


def test_behaviour_events_at_a_webhook(run) -> None:
    receiver = Receiver()
    try:
        sink = WebhookSink(receiver.url)
        for f in run:
            sink.write(f)
        sink.close()
        wait_until(lambda: len(receiver.bodies) == len(all_events(run)), "every event posted")
    finally:
        receiver.close()
    by_type = {body["type"]: body for body in receiver.bodies}
    assert by_type["person_down"]["rule"] == "man_down"
    assert by_type["lone_worker"]["zone"] == "panel"
    assert by_type["overreach"]["posture"] == "standing"


def test_behaviour_events_over_mqtt_leave_the_zone_occupancy_alone(tmp_path: Path, run) -> None:
    broker = Broker(tmp_path / "broker").start()
    sub = None
    try:
        sub = Subscriber(broker.port, "stereopose/site/#")
        settings = MqttSettings(
            host="127.0.0.1",
            port=broker.port,
            site="site",
            reconnect_min_s=0.05,
            reconnect_max_s=0.2,
            close_timeout_s=3.0,
        )
        sink = MqttSink(settings, ["panel"])
        for f in run:
            sink.write(f)
        sink.close()
        topic = "stereopose/site/events"
        wait_until(lambda: len(sub.on(topic)) == len(all_events(run)), "every event on MQTT")
        got = [json.loads(p) for p in sub.on(topic)]
        assert [g["rule"] for g in got] == [e.rule for e in all_events(run)]
        assert next(g for g in got if g["type"] == "person_down")["posture"] == "lying"
        # a lone_worker event names the panel, but nobody entered it
        occupancy = [json.loads(p) for p in sub.on("stereopose/site/zones/panel")]
        assert occupancy and all(o["people"] == [] for o in occupancy)
    finally:
        if sub is not None:
            sub.close()
        broker.stop()


def test_postures_in_the_3d_poses(tmp_path: Path, run) -> None:
    sink = PosesSink(tmp_path / "poses3d.jsonl", FPS)
    for f in run:
        sink.write(f)
    sink.close()
    records = list(read_poses(tmp_path / "poses3d.jsonl"))
    assert len(records) == len(run)
    first = {p["id"]: p for p in records[0][2]}
    last = {p["id"]: p for p in records[-1][2]}
    assert first[1]["posture"] == "standing" and first[1]["flags"] == []
    assert last[1]["posture"] == "lying"
    assert last[2]["posture"] == "standing" and last[2]["flags"] == ["arms_raised"]
    # without postures (no rules) the records are as before
    plain = PosesSink(tmp_path / "plain.jsonl", FPS)
    plain.write(FrameResult(0, 0.0, {}, run[0].people3d))
    plain.close()
    rec = json.loads((tmp_path / "plain.jsonl").read_text())
    assert "posture" not in rec["people"][0] and "flags" not in rec["people"][0]


def test_the_report_shows_postures_and_behaviour_events(tmp_path: Path, run) -> None:
    sink = PosesSink(tmp_path / "poses3d.jsonl", FPS)
    for f in run:
        sink.write(f)
    sink.close()
    poses = list(read_poses(tmp_path / "poses3d.jsonl"))
    table = postures_html(poses)
    rows = {r.split("</td>")[0]: r for r in table.split("<tr><td>")[1:]}
    assert set(rows) == {"1", "2"}
    # person 2 stood the whole 5 s, 4 of them with an arm raised
    cells = [c.removeprefix("<td>") for c in rows["2"].split("</td>")[1:-1]]
    assert cells[0] == "5.0" and cells[-2] == "4.0"
    events = behaviour_events_html(all_events(run))
    assert events.count("<tr class='alarm'>") == 3 and "man_down" in events
    assert "hips dropping" in events and "failed" not in events
    assert postures_html([(0, 0.0, [{"id": 1, "joints": []}])]) == ""  # no rules: no section
    assert behaviour_events_html([]) == ""
