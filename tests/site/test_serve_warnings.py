"""`stereopose serve` on the real demo with warnings on site: the walker's reaches into the
energized busbar are said on the speaker that covers it (RTP, heard here by a UDP listener)
and on no other, and light the beacon of a Modbus TCP IO module (pymodbus's own server), which
is off again once serve has stopped."""

from __future__ import annotations

import subprocess
import sys
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
