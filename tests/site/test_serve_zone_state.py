"""`stereopose serve` on the real demo with its busbar's state from a c104 outstation (the
test plays the utility's RTU): the busbar switched out and earthed, the walker's reaches into
it are logged as dead-zone entries (info, no incident); the breaker closed, the zone turns live
and his reaches are energized alarms again; the RTU gone, the zone is unknown (live) with a
diagnostic incident naming the RTU. status.json shows each zone's state and its source."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from brokers import free_port
from served import log_rows
from stereopose.pipeline.demo import write_serve_demo_config
from waiting import wait_until

c104 = pytest.importorskip("c104")
pytestmark = [pytest.mark.realdata, pytest.mark.slow]


def _busbar(db: Path) -> list[tuple]:
    return log_rows(
        db,
        "SELECT id, kind, type, incident, source FROM events WHERE zone = 'overhead_busbar' "
        "ORDER BY id",
    )


def test_the_busbars_state_follows_the_rtu_in_the_served_demo(tmp_path: Path) -> None:
    rtu_port = free_port()
    server = c104.Server(ip="127.0.0.1", port=rtu_port, tick_rate_ms=50)
    station = server.add_station(common_address=3)
    qf = station.add_point(io_address=3001, type=c104.Type.M_DP_TB_1)
    qe = station.add_point(io_address=3002, type=c104.Type.M_DP_TB_1)
    qf.value, qe.value = c104.Double.OFF, c104.Double.ON  # open and earthed: dead
    server.start()
    config = write_serve_demo_config(tmp_path / "demo", tmp_path / "data", free_port(), imgsz=320)
    site = tmp_path / "demo" / "demo_site.toml"
    link = f'host = "127.0.0.1", port = {rtu_port}, common_address = 3, type = "double"'
    text = site.read_text().replace(
        "margin_m = 0.3\n",
        "margin_m = 0.3\nvoltage_kv = 10\n"
        "[zones.state]\n"
        "dead_when = \"qf == 'open' and qe == 'closed'\"\n"
        "[zones.state.points]\n"
        f"qf = {{ iec104 = {{ {link}, ioa = 3001 }} }}\n"
        f"qe = {{ iec104 = {{ {link}, ioa = 3002 }} }}\n",
        1,
    )
    assert text != site.read_text()
    site.write_text(text)
    config.write_text(config.read_text().replace("[serve]\n", "[serve]\nstatus_interval_s = 1\n"))
    data = tmp_path / "data"
    db = data / "events.sqlite"
    log = tmp_path / "serve.log"
    with open(log, "ab") as f:
        proc = subprocess.Popen(
            [sys.executable, "-m", "stereopose.cli", "serve", str(config)],
            stdout=f,
            stderr=subprocess.STDOUT,
        )
    try:
        # dead: the walker's reaches are dead-zone entries, no incident
        _waited(
            lambda: any(r[2] == "zone_dead" for r in _busbar(db)) or proc.poll() is not None,
            "the busbar dead",
            log,
            timeout_s=180,
        )
        assert proc.poll() is None, log.read_text()
        _waited(
            lambda: any(r[1] == "dead" and r[2] == "enter" for r in _busbar(db)),
            "a dead-zone entry",
            log,
            timeout_s=60,
        )
        entry = next(r for r in _busbar(db) if r[1] == "dead" and r[2] == "enter")
        assert entry[3] is None and "ioa 3001" in entry[4]
        # before the RTU's first values the zone is unknown, so live (a busy machine may
        # step a while before they come); from its dead state on, no energized entry
        dead = next(r[0] for r in _busbar(db) if r[2] == "zone_dead")
        assert not [
            r for r in _busbar(db) if r[1] == "energized" and r[2] == "enter" and r[0] > dead
        ]

        def zone_state() -> dict:
            try:
                doc = json.loads((data / "status.json").read_text())
            except (OSError, ValueError):
                return {}
            return doc.get("zone_state", {}).get("zones", {}).get("overhead_busbar", {})

        wait_until(lambda: zone_state().get("state") == "dead", "status.json: dead")
        # the breaker closed: live, and the next reach is an energized alarm
        qf.value = c104.Double.ON
        qf.transmit(cause=c104.Cot.SPONTANEOUS)
        live = wait_until(
            lambda: next((r[0] for r in _busbar(db) if r[2] == "zone_live" and r[0] > dead), None),
            "the busbar live",
        )

        def energized_entries() -> list[tuple]:
            return [
                r for r in _busbar(db) if r[1] == "energized" and r[2] == "enter" and r[0] > live
            ]

        wait_until(energized_entries, "an energized entry", timeout_s=60)
        alarm = energized_entries()[0]
        assert alarm[3] is not None  # an incident
        # the RTU gone: unknown, a diagnostic incident naming it
        server.stop()
        wait_until(lambda: any(r[2] == "zone_unknown" for r in _busbar(db)), "the busbar unknown")
        unknown = next(r for r in _busbar(db) if r[2] == "zone_unknown")
        assert unknown[3] is not None and f"127.0.0.1:{rtu_port}" in unknown[4]
        wait_until(lambda: zone_state().get("state") == "unknown", "status.json: unknown")
    finally:
        proc.terminate()
        try:
            rc = proc.wait(timeout=40)
        except subprocess.TimeoutExpired:
            proc.kill()
            pytest.fail(f"serve did not stop within 40 s:\n{log.read_text()}")
        server.stop()
    assert rc == 0, log.read_text()
    assert "Traceback" not in log.read_text()


def _waited(condition, what: str, log: Path, timeout_s: float) -> None:
    """wait_until, failing with the end of serve's log (what it was doing meanwhile)."""
    try:
        wait_until(condition, what, timeout_s=timeout_s)
    except pytest.fail.Exception:
        tail = log.read_text(errors="replace")[-4000:] if log.exists() else "(no log)"
        pytest.fail(f"still waiting for {what} after {timeout_s} s; serve's log ends:\n{tail}")
