"""The event log as an outbox, against a real mosquitto: every event reaches a receiver that
confirms what it stored, exactly once in its store, across a broker restart, a receiver away,
lost messages and a replay asked for; a site without a receiver does not send its history."""

from __future__ import annotations

import json
from pathlib import Path

import paho.mqtt.client as paho
import pytest

from brokers import Broker, LogReceiver
from stereopose.io.sinks.eventwriter import SqliteSink
from stereopose.io.sinks.mqtt import MqttSettings
from stereopose.site.eventlog import EventLog
from stereopose.site.health.watchdog import Watchdog
from stereopose.site.outbox import LogOutbox, OutboxPace
from stereopose.types import Event
from waiting import wait_until

SITE = "north/yard"
BASE = "stereopose/north%2Fyard/log"


@pytest.fixture
def broker(tmp_path: Path):
    b = Broker(tmp_path / "broker").start()
    yield b
    b.stop()


@pytest.fixture
def closing():
    opened: list = []
    yield opened.append
    for thing in reversed(opened):
        thing.close()


def settings(port: int) -> MqttSettings:
    return MqttSettings(
        host="127.0.0.1", port=port, site=SITE, reconnect_min_s=0.05, reconnect_max_s=0.2
    )


class Log:
    """A real event log (SqliteSink) written k events at a time, read as the console does."""

    def __init__(self, path: Path) -> None:
        self.sink = SqliteSink(path, "site.toml", "test", wall_start=1.8e9)
        self.read = EventLog(path)
        self.k = 0

    def write(self, n: int) -> None:
        events = []
        for _ in range(n):
            self.k += 1
            kind = "enter" if self.k % 2 else "exit"
            events.append(
                Event(
                    t=self.k / 25,
                    frame=self.k,
                    person=self.k % 3,
                    zone="panel",
                    kind="energized",
                    type=kind,
                    onset_t=self.k / 25,
                )
            )
        self.sink.write_events(events)

    def ids(self) -> list[int]:
        return [e["id"] for e in self.read.after(0, limit=100_000)]

    def close(self) -> None:
        self.sink.close()


@pytest.fixture
def log(tmp_path: Path, closing) -> Log:
    lg = Log(tmp_path / "events.sqlite")
    closing(lg)
    return lg


def test_every_event_reaches_the_receiver_once_with_its_id_and_is_confirmed(broker, log, closing):
    rx = LogReceiver(broker.port)
    closing(rx)
    box = LogOutbox(settings(broker.port), log.read)
    closing(box)
    for _ in range(6):
        log.write(5)
        box.wake()
    wait_until(lambda: rx.ids() == log.ids(), "every event at the receiver")
    assert len(log.ids()) == 30
    first = rx.stored[log.ids()[0]]
    assert first["site"] == SITE and first["prev"] == 0 and first["zone"] == "panel"
    assert {"id", "t", "wall_t", "time", "type", "level", "person"} <= first.keys()
    wait_until(lambda: box.figures()["confirmed"] == log.ids()[-1], "the confirmation")
    f = box.figures()
    assert f["published"] == 30 and f["lag"] == 0 and f["malformed"] == 0


def test_a_broker_restart_in_the_middle_loses_nothing(broker, log, closing):
    rx = LogReceiver(broker.port)
    closing(rx)
    box = LogOutbox(settings(broker.port), log.read)
    closing(box)
    log.write(10)
    wait_until(lambda: len(rx.ids()) == 10, "the first events")
    broker.stop()
    log.write(20)  # stored while the broker is away
    broker.start()
    log.write(10)
    wait_until(lambda: rx.ids() == log.ids(), "every event after the restart", timeout_s=30)
    assert len(rx.ids()) == 40


def test_a_receiver_away_gets_what_it_missed_from_the_log(broker, log, closing):
    rx = LogReceiver(broker.port)
    box = LogOutbox(settings(broker.port), log.read)
    closing(box)
    log.write(5)
    wait_until(lambda: len(rx.ids()) == 5, "the first events")
    mark = rx.mark
    kept = dict(rx.stored)
    rx.close()
    log.write(25)  # the control room is down: nobody confirms
    wait_until(lambda: box.figures()["cursor"] == log.ids()[-1], "the outbox sending on")
    again = LogReceiver(broker.port, mark=mark)  # restarted, its store as it was
    again.stored.update(kept)
    closing(again)
    wait_until(lambda: again.ids() == log.ids(), "the missed events after the restart")
    wait_until(lambda: box.figures()["replays"] >= 1, "the replay counted")


def test_the_site_sends_again_when_the_mark_stays_behind(broker, log, closing):
    box = LogOutbox(settings(broker.port), log.read, pace=OutboxPace(resend_s=0.5))
    closing(box)
    rx = LogReceiver(broker.port, replay_on_start=False)
    closing(rx)
    log.write(3)
    wait_until(lambda: len(rx.ids()) == 3, "the first events")
    wait_until(lambda: box.figures()["confirmed"] == log.ids()[-1], "their confirmation")
    rx.lose(4)  # the next four never arrive; nothing after them comes either
    log.write(4)
    wait_until(lambda: box.figures()["cursor"] == log.ids()[-1], "the outbox sending on")
    # no further event shows the gap: the site's resend after resend_s fills it
    wait_until(lambda: rx.ids() == log.ids(), "the lost events sent again")
    # (counted just after paho takes each: the receiver may have them first)
    wait_until(lambda: box.figures()["resent"] >= 4, "the resends counted")


def test_the_last_events_at_the_close_reach_a_receiver_that_lost_them(broker, log, closing):
    """A service's stop: its last events stored, the outbox closed at once. Where a receiver
    confirms, the close waits for its mark (bounded) and sends again what it lost: nothing after
    them would show the gap, and no next resend comes from a stopped site."""
    box = LogOutbox(
        settings(broker.port), log.read, pace=OutboxPace(resend_s=0)
    )  # no resend while running
    rx = LogReceiver(broker.port, replay_on_start=False)
    closing(rx)
    log.write(3)
    wait_until(lambda: box.figures()["confirmed"] == log.ids()[-1], "the first confirmation")
    rx.lose(2)  # the stop's last two events never arrive the first time
    log.write(2)
    box.close(timeout_s=10.0)
    assert rx.ids() == log.ids()
    f = box.figures()
    assert f["confirmed"] == log.ids()[-1] and f["resent"] >= 2


def test_a_gap_seen_by_the_receiver_is_filled_by_a_replay(broker, log, closing):
    rx = LogReceiver(broker.port, replay_on_start=False)  # no replay but the gap's
    closing(rx)
    box = LogOutbox(settings(broker.port), log.read, pace=OutboxPace(resend_s=0))
    closing(box)
    log.write(3)
    wait_until(lambda: len(rx.ids()) == 3, "the first events")
    wait_until(lambda: box.figures()["confirmed"] == log.ids()[-1], "their confirmation")
    rx.lose(2)
    log.write(2)
    wait_until(lambda: box.figures()["cursor"] == log.ids()[-1], "the lost ones sent")
    log.write(3)  # their prev shows the gap: a replay after the mark
    wait_until(lambda: rx.ids() == log.ids(), "the gap filled")
    assert rx.replays >= 1 and len(rx.ids()) == 8


def test_a_new_receiver_gets_the_history_after_its_mark(broker, log, closing):
    log.write(5)  # before the outbox: sent only to a receiver whose mark is before them
    box = LogOutbox(settings(broker.port), log.read)
    closing(box)
    rx = LogReceiver(broker.port, mark=0, replay_on_start=False)
    closing(rx)
    # rx's confirmation (mark 0) is the first the outbox hears: it starts again after it
    log.write(2)
    wait_until(lambda: rx.ids() == log.ids(), "the history and the new events")
    assert len(rx.ids()) == 7


def test_only_new_events_go_out_while_no_receiver_confirms(broker, log, closing):
    from brokers import Subscriber

    log.write(5)
    sub = Subscriber(broker.port, f"{BASE}/events")
    closing(sub)
    box = LogOutbox(settings(broker.port), log.read)
    closing(box)
    log.write(2)
    wait_until(lambda: len(sub.on(f"{BASE}/events")) == 2, "the new events")
    got = [json.loads(p) for p in sub.on(f"{BASE}/events")]
    assert [e["id"] for e in got] == log.ids()[5:]
    assert got[0]["prev"] == log.ids()[4]  # a receiver with mark < prev asks for a replay


def test_malformed_control_messages_are_counted_and_ignored(broker, log, closing):
    box = LogOutbox(settings(broker.port), log.read)
    closing(box)
    c = paho.Client(paho.CallbackAPIVersion.VERSION2, protocol=paho.MQTTv311)
    c.connect("127.0.0.1", broker.port)
    c.loop_start()
    wait_until(lambda: box.figures()["subscribed"], "the outbox subscribed")
    for payload in (
        b"not json",
        b'{"events": -1}',
        b'{"events": true}',
        b"\xff\xfe",
        b'{"after_id": "7"}',
        b"[1, 2]",
    ):
        c.publish(f"{BASE}/confirmed", payload, qos=1).wait_for_publish(5)
    c.publish(f"{BASE}/replay", b'{"after_id": 1e400}', qos=1).wait_for_publish(5)
    wait_until(lambda: box.figures()["malformed"] == 7, "every malformed message counted")
    assert box.figures()["confirmed"] is None
    c.loop_stop()
    c.disconnect()
    log.write(1)
    wait_until(lambda: box.figures()["published"] == 1, "sending still works")


def test_deeply_nested_control_messages_never_stop_the_outbox(broker, log, closing):
    box = LogOutbox(settings(broker.port), log.read)
    closing(box)
    c = paho.Client(paho.CallbackAPIVersion.VERSION2, protocol=paho.MQTTv311)
    c.connect("127.0.0.1", broker.port)
    c.loop_start()
    wait_until(lambda: box.figures()["subscribed"], "the outbox subscribed")
    deep = b"[" * 20_000 + b"]" * 20_000
    ack = box.topics["ack"].replace(SITE, "north%2Fyard")
    for topic in (f"{BASE}/replay", f"{BASE}/confirmed", ack):
        c.publish(topic, deep, qos=1).wait_for_publish(5)
    wait_until(lambda: box.figures()["malformed"] == 3, f"each counted {box.figures()}")
    c.loop_stop()
    c.disconnect()
    log.write(2)  # its MQTT thread alive: the site's events still leave
    wait_until(lambda: box.figures()["published"] == 2, "sending still works")


@pytest.mark.filterwarnings("ignore::pytest.PytestUnhandledThreadExceptionWarning")
def test_dead_threads_are_started_again_by_the_watchdog_and_health_says_so_meanwhile(
    broker, log, closing
):
    rx = LogReceiver(broker.port)
    closing(rx)
    box = LogOutbox(settings(broker.port), log.read, pace=OutboxPace(resend_s=0.5))
    closing(box)
    dog = Watchdog(interval_s=3600)  # its rounds asked for by hand here
    dog.add("outbox", box.ensure_running)
    log.write(2)
    wait_until(lambda: box.figures()["confirmed"] == 2, "the first events confirmed")
    assert box.health().ok
    message, send = box._message, box._send

    def dies(*_):  # what no `except Exception` catches: paho's thread ends
        box._message = message
        raise SystemExit("gone")

    def sender_dies():
        box._send = send
        raise SystemExit("gone")

    box._message = dies
    box.wake()
    rx.client.publish(f"{BASE}/replay", b'{"after_id": 0}', qos=1)
    wait_until(lambda: not box.health().ok, "health not ok while paho's thread is down")
    assert "MQTT client" in box.health().reason
    dog.check()
    assert box.figures()["restarts"] == 1 and box.health().ok
    box._send = sender_dies
    box.wake()
    wait_until(lambda: not box._thread.is_alive(), "the sending thread's end")
    assert "sending thread" in box.health().reason
    log.write(3)  # written while it is down: sent once it runs again
    dog.check()
    assert box.figures()["restarts"] == 2
    wait_until(lambda: rx.ids() == log.ids(), "every event at the receiver after the restarts")
    wait_until(lambda: box.figures()["confirmed"] == 5, "the later events confirmed")
    assert box.health().ok
