"""Incidents between a site and the control room, in-process against a real mosquitto: a
site's incidents (a real incident book storing in a real event log, published by its outbox)
held centrally with their latest state; an acknowledgement asked by the control room reaches
the site's book as "USER via NAME" and comes back acknowledged, also when asked while the
broker is away; one made at the site reaches the control room; a site offline and a site's
clock off raise the control room's own incidents; malformed commands are counted."""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import paho.mqtt.client as paho
import pytest

from brokers import Broker
from stereopose.alarms import IncidentBook
from stereopose.config.service import ControlRoomConfig
from stereopose.controlroom.enrolment import Enrolment, broker_hash
from stereopose.controlroom.ingest import Ingest
from stereopose.controlroom.store import ControlStore
from stereopose.io.sinks.eventwriter import SqliteSink
from stereopose.io.sinks.mqtt import MqttSettings
from stereopose.pipeline.incidents import IncidentStep
from stereopose.pipeline.step_rules import step_chain
from stereopose.site.desk import IncidentDesk
from stereopose.site.eventlog import EventLog
from stereopose.site.outbox import LogOutbox, OutboxPace
from stereopose.types import Event, People3D
from waiting import wait_until

WALL_START = 1.8e9


def _settings(port: int, site: str = "north") -> MqttSettings:
    return MqttSettings(
        host="127.0.0.1", port=port, site=site, reconnect_min_s=0.05, reconnect_max_s=0.2
    )


class _Script:
    """The step's events, given in turn (the role ServeEvents plays in serve)."""

    def __init__(self) -> None:
        self.next: list[Event] = []

    def update(self, people3d) -> list[Event]:
        out, self.next = self.next, []
        return out


class Site:
    """A site as serve wires it: an incident book whose records and events go to the event
    log, and the log's outbox with the book's acknowledge as its commands' way in."""

    def __init__(
        self,
        folder: Path,
        port: int,
        name: str = "north",
        pace: OutboxPace | None = None,
        plan: dict | None = None,
        desk: IncidentDesk | None = None,
    ) -> None:
        self.t, self.frame = 0.0, 0
        self.sink = SqliteSink(
            folder / f"{name}.sqlite", "site.toml", "test", wall_start=WALL_START
        )
        self.script = _Script()
        self.step = IncidentStep(
            IncidentBook(),
            step_chain(self.script),
            outputs=[self.sink.write_changes],
            clock=lambda: self.t,
            wall_start=WALL_START,
        )
        self.box = LogOutbox(
            _settings(port, name),
            EventLog(folder / f"{name}.sqlite"),
            pace or OutboxPace(),
            # serve's: the desk's acknowledge, the step attached to it once it runs
            acknowledger=self.step.acknowledge if desk is None else desk.acknowledge,
            plan=plan,
        )

    def run(self, *events: Event) -> list[Event]:
        self.frame += 1
        self.t = max(self.t + 0.1, *(e.t for e in events)) if events else self.t + 0.1
        self.script.next = list(events)
        p = People3D(
            frame=self.frame,
            joints=np.zeros((0, 17, 3)),
            conf=np.ones((0, 17)),
            ids=np.arange(0),
            reprojection_px=np.zeros((0, 17)),
            views=np.full((0, 17), 2),
            detections=np.zeros((0, 2), dtype=int),
        )
        out, _ = self.step.step(self.t, self.frame, p)
        self.sink.write_events(out)
        self.box.wake()
        return out

    def enter(self, zone: str = "busbar", person: int = 7, type_: str = "enter") -> int:
        t = self.t + 0.1
        out = self.run(
            Event(
                t=t,
                frame=self.frame + 1,
                person=person,
                zone=zone,
                kind="energized",
                type=type_,
                onset_t=t,
            )
        )
        return out[0].incident

    def record(self, incident: int):
        return self.step.book.get(incident)

    def close(self) -> None:
        self.box.close()
        self.sink.close()


@pytest.fixture
def broker(tmp_path: Path):
    b = Broker(tmp_path / "broker").start()
    yield b
    b.stop()


@pytest.fixture
def room(broker, tmp_path: Path):
    store = ControlStore(tmp_path / "control.sqlite")
    for site in ("north", "east"):
        Enrolment(store).add(site, broker_hash("pw", iterations=1), 1.8e9)
    room = ControlRoomConfig(command_resend_s=0.5, name="central")
    ingest = Ingest(_settings(broker.port, "unused"), store, room, replay_every_s=0.2)
    wait_until(lambda: ingest.subscribed, "the control room subscribed")
    yield store, ingest
    ingest.close()
    store.close()


def _room_states(store: ControlStore, site: str, kind: str) -> list[str]:
    return [i["state"] for i in store.incidents(site=site) if i.get("kind") == kind]


def _central(store: ControlStore, site: str, incident: int) -> dict | None:
    return store.incident(site, incident)


def test_a_sites_incidents_are_held_centrally_with_their_latest_state(broker, room, tmp_path):
    store, _ingest = room
    site = Site(tmp_path, broker.port)
    try:
        first = site.enter()
        wait_until(lambda: _central(store, "north", first) is not None, "the incident there")
        assert _central(store, "north", first)["state"] == "active"
        site.enter(type_="exit")
        site.enter()  # a re-entry: the same incident, one more occurrence
        wait_until(
            lambda: (_central(store, "north", first) or {}).get("occurrences") == 2,
            "its second occurrence",
        )
        other = site.enter(zone="feeder", person=3)
        assert other != first
        wait_until(lambda: _central(store, "north", other) is not None, "the second incident")
        listed = store.incidents(site="north", state="open")
        assert sorted(i["id"] for i in listed if i["source"] == "site") == sorted([first, other])
        assert all(i["site"] == "north" and i["priority"] == 1 for i in listed)
        assert store.open_counts()["north"] == {"1": 2}
        marks = store.incident_marks()["north"]
        assert marks == site.box.figures()["incidents"]["cursor"]
    finally:
        site.close()


def test_an_ack_asked_centrally_reaches_the_site_and_comes_back(broker, room, tmp_path):
    store, ingest = room
    site = Site(tmp_path, broker.port)
    try:
        inc = site.enter()
        wait_until(lambda: _central(store, "north", inc) is not None, "the incident there")
        command = ingest.ask_ack("north", inc, "olga")
        wait_until(lambda: site.record(inc).acked_by == "olga via central", "the site's ack")
        site.run()  # the change is stored with the site's next step, as every change is
        wait_until(
            lambda: (_central(store, "north", inc) or {}).get("acked_by") == "olga via central",
            "the ack back in the control room",
        )
        assert _central(store, "north", inc)["state"] == "acknowledged"
        wait_until(lambda: not store.pending_commands(), "the command answered")
        # (counted once the answer is stored: just after the command leaves the pending list)
        wait_until(lambda: ingest.figures()["commands_done"] == 1, "the answer counted")
        # asked again (a second operator): the site keeps the first, answers "already"
        ingest.ask_ack("north", inc, "paul")
        wait_until(lambda: not store.pending_commands(), "the second answered")
        assert site.record(inc).acked_by == "olga via central"
        with store.reading("read the commands") as run:
            results = dict(run("SELECT id, result FROM commands").fetchall())
        assert results[command] == "acknowledged" and sorted(results.values()) == [
            "acknowledged",
            "already",
        ]
        # an incident the site does not hold: answered unknown, not asked for ever
        ingest.ask_ack("north", 10_000, "olga")
        wait_until(lambda: not store.pending_commands(), "the unknown one answered")
        # acknowledged at the site: the control room sees it
        other = site.enter(zone="feeder", person=3)
        wait_until(lambda: _central(store, "north", other) is not None, "the second incident")
        site.step.acknowledge(other, "sam")
        site.run()  # the change is stored with the next step
        wait_until(
            lambda: (_central(store, "north", other) or {}).get("acked_by") == "sam",
            "the site's ack in the control room",
        )
    finally:
        site.close()


def test_an_ack_asked_before_the_sites_book_runs_is_unavailable_then_done(broker, room, tmp_path):
    """serve makes the outbox before the frame loop runs the incident book: a command that
    comes meanwhile is answered "unavailable" (not "unknown"), and one asked once the book
    runs acknowledges."""
    store, ingest = room
    desk = IncidentDesk()
    site = Site(tmp_path, broker.port, desk=desk)
    try:
        inc = site.enter()
        wait_until(lambda: _central(store, "north", inc) is not None, "the incident there")
        early = ingest.ask_ack("north", inc, "olga")
        wait_until(lambda: not store.pending_commands(), "the early command answered")
        desk.attach(site.step)
        late = ingest.ask_ack("north", inc, "olga")
        wait_until(lambda: site.record(inc).acked_by == "olga via central", "the site's ack")
        wait_until(lambda: not store.pending_commands(), "the later command answered")
        with store.reading("read the commands") as run:
            results = dict(run("SELECT id, result FROM commands").fetchall())
        assert results == {early: "unavailable", late: "acknowledged"}
    finally:
        site.close()


def test_an_ack_asked_while_the_broker_is_away_arrives_when_it_is_back(broker, room, tmp_path):
    store, ingest = room
    site = Site(tmp_path, broker.port)
    try:
        inc = site.enter()
        wait_until(lambda: _central(store, "north", inc) is not None, "the incident there")
        broker.stop()
        ingest.ask_ack("north", inc, "olga")  # stored; sent again until answered
        site.enter(zone="feeder", person=3)  # the site goes on meanwhile
        broker.start()
        wait_until(
            lambda: site.record(inc).acked_by == "olga via central", "the site's ack", timeout_s=30
        )
        site.run()
        wait_until(
            lambda: (_central(store, "north", inc) or {}).get("state") == "acknowledged",
            "the ack back",
            timeout_s=30,
        )
        wait_until(lambda: not store.pending_commands(), "the command answered", timeout_s=30)
        assert len(store.incidents(site="north")) == 2
    finally:
        site.close()


def test_a_site_offline_and_a_clock_off_raise_the_control_rooms_incidents(broker, room, tmp_path):
    store, _ingest = room
    site = Site(tmp_path, broker.port, pace=OutboxPace(heartbeat_s=0.2))
    try:
        site.enter()
        wait_until(lambda: store.incidents(site="north"), "the site known")
        c = paho.Client(paho.CallbackAPIVersion.VERSION2, protocol=paho.MQTTv311)
        c.connect("127.0.0.1", broker.port)
        c.loop_start()
        try:  # a second site whose clock is 60 s ahead, then right again
            beat = {"last_id": 0, "time": 0.0}

            def ahead() -> bool:
                c.publish(
                    "stereopose/east/log/heartbeat", json.dumps({**beat, "time": time.time() + 60})
                )
                return any(
                    i["kind"] == "site_clock" and i["state"] == "active"
                    for i in store.incidents(site="east")
                )

            wait_until(ahead, "the clock incident", poll_s=0.3)
            clock = next(i for i in store.incidents(site="east") if i["kind"] == "site_clock")
            assert clock["source"] == "control_room" and clock["priority"] == 3
            assert "+60" in clock["detail"]

            def right() -> bool:
                c.publish(
                    "stereopose/east/log/heartbeat", json.dumps({**beat, "time": time.time()})
                )
                return store.incidents(site="east")[0]["state"] == "cleared"

            wait_until(right, "the clock incident cleared", poll_s=0.3)
            # malformed commands at a site: counted, never acted on
            c.publish("stereopose/north/commands/ack", b"{not json", qos=1)
            c.publish(
                "stereopose/north/commands/ack",
                json.dumps({"command": "1", "incident": "x", "by": "a", "from": "b"}),
                qos=1,
            )
            wait_until(lambda: site.box.figures()["malformed"] == 2, "the bad commands counted")
            # the site's availability gone offline (its last will, or a clean stop): an
            # incident of the control room's, acknowledged there; back online: closed
            c.publish("stereopose/north/available", b"offline", qos=1, retain=True)
            wait_until(
                lambda: _room_states(store, "north", "site_offline") == ["active"],
                "the offline incident",
            )
            offline = [i for i in store.incidents(site="north") if i.get("kind") == "site_offline"]
            acked = store.ack_room_incident(offline[0]["id"], "olga", 1.0)
            assert acked["state"] == "acknowledged" and acked["acked_by"] == "olga"
            assert store.open_counts()["north"]["2"] == 1
            c.publish("stereopose/north/available", b"online", qos=1, retain=True)
            wait_until(
                lambda: _room_states(store, "north", "site_offline") == ["closed"],
                "the offline incident closed",
            )
        finally:
            c.loop_stop()
            c.disconnect()
    finally:
        site.close()
