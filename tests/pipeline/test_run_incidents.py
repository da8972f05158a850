"""Incidents in a recorded run: `stereopose run` (the real demo, as `make demo` runs it) keeps
the same incident book as `serve`: each alarm-level event names its incident and priority in
events.jsonl and events.sqlite, the incidents' records are in the log, and the report groups
the alarms by incident."""

from __future__ import annotations

import json
import sqlite3
from pathlib import Path

import pytest

pytestmark = [pytest.mark.realdata, pytest.mark.slow]


def test_a_runs_alarms_belong_to_incidents_as_the_service_would_raise_them(real_demo_dir: Path):
    lines = (real_demo_dir / "events.jsonl").read_text().splitlines()
    events = [json.loads(line) for line in lines]
    alarms = [e for e in events if e.get("incident") is not None]
    assert alarms, "the demo's man reaches into the busbar: alarms"
    assert all(e["priority"] in (1, 2, 3, 4) for e in alarms)
    # entries and approaches of one person at one zone are one incident, with a count
    by_incident: dict[int, set] = {}
    for e in alarms:
        by_incident.setdefault(e["incident"], set()).add((e["zone"], e["person"]))
    assert all(len(hazards) == 1 for hazards in by_incident.values())
    assert len(by_incident) < len(alarms)  # repeated reaches: occurrences, not new incidents
    # the log holds the same ids on its events and the incidents' records
    with sqlite3.connect(real_demo_dir / "events.sqlite") as db:
        logged = dict(db.execute("SELECT id, incident FROM events WHERE incident IS NOT NULL"))
        records = {
            i: {**json.loads(r), "zone": z}
            for i, z, r in db.execute("SELECT id, zone, record FROM incidents")
        }
    assert set(logged.values()) == set(by_incident) <= set(records)
    for i, rec in records.items():
        assert rec["occurrences"] >= 1 and rec["priority"] in (1, 2, 3, 4)
        if i in by_incident and rec["zone"] is not None:  # a zone's (a rule's has none)
            assert rec["zone"] == next(iter(by_incident[i]))[0]
    # info-level events belong to none
    assert all(e["priority"] is None for e in events if e.get("incident") is None)
    page = (real_demo_dir / "report.html").read_text()
    assert "Alarms by incident" in page
    for i in by_incident:
        assert f"incident {i}" in page
