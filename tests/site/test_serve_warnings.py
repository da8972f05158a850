"""`stereopose serve` on the real demo with warnings on site: the walker's reaches into the
energized busbar are said on the speaker that covers it (RTP, heard here by a UDP listener)
and on no other, and light the beacon of a Modbus TCP IO module (pymodbus's own server), which
is off again once serve has stopped."""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import pytest

from brokers import free_port
from modbus_device import IoModule
from rtp_listener import Listener
from served import log_rows
from stereopose.pipeline.demo import write_serve_demo_config
from waiting import wait_until

pytestmark = [pytest.mark.realdata, pytest.mark.slow]

FAR_PANEL = """
[[zones]]
name = "far_panel"
kind = "energized"
polygon = [[40.0, 40.0], [41.0, 40.0], [41.0, 41.0], [40.0, 41.0]]
z = [0.0, 2.5]
margin_m = 0.5
"""


def _busbar_alarms(db: Path) -> list[tuple]:
    return log_rows(
        db,
        "SELECT id, type, incident FROM events WHERE zone = 'overhead_busbar' "
        "AND kind = 'energized' AND type IN ('enter', 'approach') ORDER BY id",
    )


def test_the_busbars_alarms_are_said_on_its_speaker_and_light_its_beacon(tmp_path: Path):
    busbar_ear, panel_ear = Listener(), Listener()
    module = IoModule().start()
    config = write_serve_demo_config(tmp_path / "demo", tmp_path / "data", free_port(), imgsz=320)
    site = tmp_path / "demo" / "demo_site.toml"
    site.write_text(
        site.read_text()
        + FAR_PANEL
        + '\n[warnings]\nlanguage = "en"\nrepeat_s = 2.0\n\n'
        + "[[speakers]]\n"
        + f'name = "pa_busbar"\nurl = "rtp://127.0.0.1:{busbar_ear.port}"\n'
        + 'zones = ["overhead_busbar"]\n\n'
        + "[[speakers]]\n"
        + f'name = "pa_panel"\nurl = "rtp://127.0.0.1:{panel_ear.port}"\nzones = ["far_panel"]\n\n'
        + "[[signals]]\n"
        + f'name = "tower"\nhost = "127.0.0.1"\nport = {module.port}\n'
        + 'coils = { beacon = 0, siren = 1 }\nzones = ["overhead_busbar"]\n'
    )
    db = tmp_path / "data" / "events.sqlite"
    log = tmp_path / "serve.log"
    with open(log, "ab") as f:
        proc = subprocess.Popen(
            [sys.executable, "-m", "stereopose.cli", "serve", str(config)],
            stdout=f,
            stderr=subprocess.STDOUT,
        )
    lit = []
    try:
        wait_until(
            lambda: _busbar_alarms(db) or proc.poll() is not None, "a busbar alarm", timeout_s=180
        )
        assert proc.poll() is None, log.read_text()

        def heard_and_lit() -> bool:
            busbar_ear.take(lambda: True)  # what has come so far
            busbar_ear.take(lambda: len(busbar_ear.packets) > 0)
            if module.coils(0) == [True]:
                lit.append(True)
            return bool(busbar_ear.packets) and bool(lit)

        wait_until(heard_and_lit, "the busbar's page and its beacon", timeout_s=60)
        assert all(p[2] == 0 and len(p[5]) == 160 for p in busbar_ear.packets)
        assert any(p[1] for p in busbar_ear.packets)  # a talkspurt's first packet
        panel_ear.take(lambda: True)
        assert panel_ear.packets == []  # far from everyone: its speaker says nothing
        assert "warnings on site: 2 speaker(s), 1 signal(s)" in log.read_text()  # said at start
        # the IO module gone: one incident, cleared once it answers again
        module.stop()
        wait_until(lambda: _output_rows(db, "warning_output_down"), "the beacon's module down")
        ((incident,),) = _output_rows(db, "warning_output_down")
        assert incident is not None  # an incident of its own
        module = IoModule(port=module.port).start()
        wait_until(lambda: _output_rows(db, "warning_output_back"), "it answers again")
        assert len(_output_rows(db, "warning_output_down")) == 1
    finally:
        proc.terminate()
        try:
            rc = proc.wait(timeout=40)
        except subprocess.TimeoutExpired:
            proc.kill()
            pytest.fail(f"serve did not stop within 40 s:\n{log.read_text()}")
        off = module.coils(0, 2)
        module.stop()
    assert rc == 0, log.read_text()
    assert off == [False, False]  # stopped: nothing left on
    assert "Traceback" not in log.read_text()


def _output_rows(db: Path, type_: str) -> list[tuple]:
    return log_rows(db, f"SELECT incident FROM events WHERE type = '{type_}' AND source = 'tower'")


def _dead_rows(db: Path) -> list[tuple]:
    return log_rows(
        db,
        "SELECT id FROM events WHERE zone = 'overhead_busbar' AND kind = 'dead' "
        "AND type IN ('enter', 'approach')",
    )


def _zone_states(db: Path, type_: str) -> list[int]:
    rows = log_rows(
        db, f"SELECT id FROM events WHERE zone = 'overhead_busbar' AND type = '{type_}'"
    )
    return [r[0] for r in rows]


def _quiet_for(ear: Listener, seconds: float) -> bool:
    """Whether no packet came in the last `seconds` (a condition polled by ear.take)."""
    return not ear.packets or ear.packets[-1][0] < time.monotonic() - seconds


def test_a_dead_busbar_stays_silent_and_warns_again_once_live(tmp_path: Path):
    """The busbar's breaker reads open (MQTT, retained, before serve starts): the walker's
    reaches are logged in a dead zone and nothing sounds or lights; its breaker closed, the
    next reach is said and lit."""
    import paho.mqtt.client as paho

    from brokers import Broker

    broker = Broker(tmp_path / "broker").start()
    pub = paho.Client(paho.CallbackAPIVersion.VERSION2)
    pub.connect("127.0.0.1", broker.port)
    pub.loop_start()
    pub.publish("scada/qf1", "open", qos=1, retain=True).wait_for_publish(10)
    ear, module = Listener(), IoModule().start()
    config = write_serve_demo_config(tmp_path / "demo", tmp_path / "data", free_port(), imgsz=320)
    config.write_text(
        config.read_text().replace(
            "[serve]\n",
            f'[mqtt]\nhost = "127.0.0.1"\nport = {broker.port}\nsite = "demo"\n\n[serve]\n',
            1,
        )
    )
    site = tmp_path / "demo" / "demo_site.toml"
    state = 'state = { mqtt = { topic = "scada/qf1", energized_when = "closed" } }\n'
    site.write_text(
        site.read_text().replace('name = "overhead_busbar"\n', 'name = "overhead_busbar"\n' + state)
        + '\n[warnings]\nrepeat_s = 2.0\n\n[[speakers]]\nname = "pa_busbar"\n'
        + f'url = "rtp://127.0.0.1:{ear.port}"\nzones = ["overhead_busbar"]\n\n'
        + f'[[signals]]\nname = "tower"\nhost = "127.0.0.1"\nport = {module.port}\n'
        + 'coils = { beacon = 0 }\nzones = ["overhead_busbar"]\n'
    )
    db, log = tmp_path / "data" / "events.sqlite", tmp_path / "serve.log"
    with open(log, "ab") as f:
        proc = subprocess.Popen(
            [sys.executable, "-m", "stereopose.cli", "serve", str(config)],
            stdout=f,
            stderr=subprocess.STDOUT,
        )
    lit: list[bool] = []
    try:
        wait_until(
            lambda: _zone_states(db, "zone_dead") or proc.poll() is not None,
            "the busbar known dead",
            timeout_s=180,
        )
        assert proc.poll() is None, log.read_text()
        (dead_at,) = _zone_states(db, "zone_dead")
        # what was said and lit while its state was not known yet (live until then) ends
        wait_until(lambda: module.coils(0) == [False], "the beacon off")
        ear.take(lambda: _quiet_for(ear, 1.0))

        def dead_reaches() -> bool:
            lit.extend(module.coils(0))
            return len([r for r in _dead_rows(db) if r[0] > dead_at]) >= 2 or bool(
                proc.poll() is not None
            )

        ear.packets.clear()
        wait_until(dead_reaches, "the walker's reaches into the dead busbar", timeout_s=240)
        assert proc.poll() is None, log.read_text()
        ear.take(lambda: True)
        assert ear.packets == [] and not any(lit)  # dead: nothing said, nothing lit
        assert [a for a in _busbar_alarms(db) if a[0] > dead_at] == []
        pub.publish("scada/qf1", "closed", qos=1, retain=True).wait_for_publish(10)

        def heard() -> bool:
            ear.take(lambda: len(ear.packets) > 0)
            return bool(ear.packets) or proc.poll() is not None

        wait_until(heard, "the live busbar's page", timeout_s=180)
        assert proc.poll() is None, log.read_text()
        wait_until(lambda: _zone_states(db, "zone_live"), "the busbar live in the log")
        wait_until(lambda: _busbar_alarms(db), "the reach an alarm again")
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=40)
        except subprocess.TimeoutExpired:
            proc.kill()
        module.stop()
        pub.loop_stop()
        broker.stop()
    assert "Traceback" not in log.read_text()
