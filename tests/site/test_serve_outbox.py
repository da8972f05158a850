"""The event log as an outbox in a real `stereopose serve` on the looped real demo, with a
real mosquitto and a receiver that confirms what it stores: after a kill -9 of the service and
a restart, the receiver holds every event of events.sqlite, each once, with the ids of the
log; a stop's last events go out with the next start."""

from __future__ import annotations

import json
import sqlite3
import time

import pytest
from test_serve import _start, _stop  # the same serve process and stop

from brokers import Broker, LogReceiver, free_port
from stereopose.pipeline.demo import write_serve_demo_config
from waiting import wait_until

pytestmark = [pytest.mark.realdata, pytest.mark.slow]


def _ids(db) -> list[int]:
    if not db.exists():
        return []
    con = sqlite3.connect(f"file:{db}?mode=ro", uri=True, timeout=5)
    try:
        return [i for (i,) in con.execute("SELECT id FROM events ORDER BY id")]
    except sqlite3.OperationalError:  # not made yet
        return []
    finally:
        con.close()


def _status(tmp_path) -> dict:
    return json.loads((tmp_path / "data" / "status.json").read_text())


def _outbox_up(tmp_path, since: float) -> bool:
    """Whether a status.json written after `since` (wall time) says the outbox is connected."""
    try:
        status = _status(tmp_path)
    except (OSError, ValueError):
        return False
    return status["written_at"] > since and bool(status.get("outbox", {}).get("connected"))


def test_every_served_event_reaches_the_receiver_once_across_a_kill_9(tmp_path):
    broker = Broker(tmp_path / "broker").start()
    config = write_serve_demo_config(tmp_path / "demo", tmp_path / "data", free_port(), imgsz=320)
    config.write_text(
        config.read_text().replace(
            "[serve]\n",
            f'[mqtt]\nhost = "127.0.0.1"\nport = {broker.port}\nsite = "demo"\n'
            "outbox_resend_s = 2\n\n[serve]\n",
            1,
        )
    )
    db, log = tmp_path / "data" / "events.sqlite", tmp_path / "serve.log"
    rx = LogReceiver(broker.port, base="stereopose/demo/log")
    try:
        proc = _start(config, log)
        try:
            wait_until(lambda: len(_ids(db)) >= 3, "events in the log", timeout_s=120, poll_s=0.5)
            wait_until(
                lambda: set(_ids(db)[:3]) <= set(rx.ids()), "them at the receiver", timeout_s=30
            )
        finally:
            proc.kill()
            proc.wait(timeout=10)
        first_run = _ids(db)
        received_before = rx.received
        proc = _start(config, log)
        try:
            wait_until(
                lambda: len(_ids(db)) >= len(first_run) + 3,
                "events of the new run",
                timeout_s=120,
                poll_s=0.5,
            )
        finally:
            rc = _stop(proc, log)
        assert rc == 0, log.read_text()
        # the stop sent what the log held: the run's last status (written once the outbox
        # closed) counts each event the run stored published once (the first run's leftovers
        # are sent again, not published anew)
        second_run = _ids(db)
        outbox = _status(tmp_path)["outbox"]
        assert outbox["published"] == len(second_run) - len(first_run) > 0, outbox
        assert outbox["cursor"] == second_run[-1] and outbox["malformed"] == 0, outbox
        # a kill left nothing unsent for ever: the receiver holds every event of the log, each
        # once, as the log numbers them
        started = time.time()
        proc = _start(config, log)
        try:  # (this run's outbox connected: a stop before it would test nothing)
            wait_until(lambda: _outbox_up(tmp_path, started), "the outbox connected", timeout_s=120)
            wait_until(
                lambda: rx.ids() == _ids(db), "every event of the log at the receiver", timeout_s=60
            )
        finally:
            rc = _stop(proc, log)
        assert rc == 0, log.read_text()
        stored = rx.stored
        assert all(stored[i]["site"] == "demo" and stored[i]["id"] == i for i in stored)
        assert len(_ids(db)) > len(first_run) > 0 and rx.received > received_before
        # the third run published its own events only (none, if the loop stored none before
        # the stop), each once
        third_run, outbox = _ids(db), _status(tmp_path)["outbox"]
        assert outbox["published"] == len(third_run) - len(second_run), outbox
        assert outbox["cursor"] == third_run[-1] and outbox["malformed"] == 0, outbox
    finally:
        rx.close()
        broker.stop()
