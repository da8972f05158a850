"""Incidents in a real `stereopose serve` process on the looped real demo, with a real
mosquitto: alarm events carry their incident and priority in events.sqlite, each incident is
one row of the incidents table and its changes reach the MQTT incidents topic; after a kill -9
and a restart the open incidents are restored once (never duplicated, new ids above the old),
and the restart's closing exits clear those whose person is gone."""

from __future__ import annotations

import json

import pytest
from test_serve import _start, _stop  # the same serve process and stop

from brokers import Broker, Subscriber, free_port
from served import log_rows
from stereopose.pipeline.demo import write_serve_demo_config
from waiting import wait_until

pytestmark = [pytest.mark.realdata, pytest.mark.slow]


@pytest.fixture
def setup(tmp_path):
    broker = Broker(tmp_path / "broker").start()
    port = free_port()
    config = write_serve_demo_config(tmp_path / "demo", tmp_path / "data", port, imgsz=320)
    text = config.read_text().replace(
        "[serve]\n",
        f'[mqtt]\nhost = "127.0.0.1"\nport = {broker.port}\nsite = "demo"\n\n[serve]\n',
        1,
    )
    config.write_text(text)
    sub = Subscriber(broker.port, "stereopose/demo/incidents")
    yield config, tmp_path / "data" / "events.sqlite", sub, tmp_path / "serve.log"
    sub.close()
    broker.stop()


def test_incidents_in_serve_survive_kill_9_once(setup):
    config, db, sub, log = setup
    proc = _start(config, log)
    try:
        wait_until(
            lambda: log_rows(db, "SELECT id FROM incidents"),
            "an incident in the log",
            timeout_s=120,
            poll_s=0.5,
        )
        wait_until(lambda: sub.on("stereopose/demo/incidents"), "the incidents topic", timeout_s=30)
    finally:
        proc.kill()
        proc.wait(timeout=10)
    change = json.loads(sub.on("stereopose/demo/incidents")[0])
    assert change["change"] == "raised" and change["incident"]["id"] >= 1
    alarms = log_rows(db, "SELECT incident, priority FROM events WHERE incident IS NOT NULL")
    stored = {i for (i,) in log_rows(db, "SELECT id FROM incidents")}
    assert alarms and {i for i, _ in alarms} <= stored and all(p for _, p in alarms)
    before = dict(log_rows(db, "SELECT id, state FROM incidents"))
    top = max(before)
    n_events = log_rows(db, "SELECT MAX(id) FROM events")[0][0]
    proc = _start(config, log)
    try:
        wait_until(
            lambda: log_rows(
                db,
                f"SELECT id FROM events WHERE id > {n_events} "
                "AND incident IS NOT NULL AND restart = 0",
            ),
            "an alarm event of the new run",
            timeout_s=120,
            poll_s=0.5,
        )
    finally:
        rc = _stop(proc, log)
    assert rc == 0, log.read_text()
    left_open = sum(1 for state in before.values() if state != "closed")
    if left_open:  # taken back by the new run's book, each once
        assert f"restart: {left_open} incident(s) left open" in log.read_text()
    after = log_rows(db, "SELECT id, state, record FROM incidents ORDER BY id")
    ids = [i for i, _, _ in after]
    assert len(ids) == len(set(ids)) and set(before) <= set(ids)
    new = [i for i in ids if i not in before]
    assert all(i > top for i in new)
    # at most one open incident per hazard: a restored one is never raised again beside it
    keys = [tuple(json.loads(r)["key"]) for _, s, r in after if s in ("active", "acknowledged")]
    assert len(keys) == len(set(keys))
    # every event of the new run names an incident the log holds
    named = {
        i
        for (i,) in log_rows(
            db, f"SELECT incident FROM events WHERE id > {n_events} AND incident IS NOT NULL"
        )
    }
    assert named <= set(ids)
