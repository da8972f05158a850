"""Incidents through the service's back end, on a real event log (the real SQLite sink) and a
real server with the console: events carry their incident and priority (SQLite, JSON lines,
/api/events); repeated entries of one person into one zone are one incident with a count;
GET /api/incidents filters; ack and shelve (operator ok, viewer 403, unknown 404, bad shelving
422) reach the book and the store; an event's ack acknowledges its incident; ids from the
log's mark, above the old ones after a restart, open incidents restored once."""

from __future__ import annotations

import json
import sqlite3

import pytest
from test_console_api import _Stream

from consoled import WALL_START, console_server, demo_plan, zone_event
from served import frame_result
from stereopose.alarms import AlarmSettings, IncidentBook
from stereopose.io.sinks.events import JsonlSink
from stereopose.io.sinks.incidents import IncidentIds
from stereopose.pipeline.incidents import IncidentStep
from stereopose.pipeline.step_rules import step_chain
from stereopose.site.restart import Resume
from stereopose.types import Event
from waiting import wait_until

pytestmark = pytest.mark.realdata  # the real demo's rig and site


@pytest.fixture(scope="module")
def plan(tmp_path_factory):
    return demo_plan(tmp_path_factory.mktemp("plan"))


class Script:
    """The step's events, given in turn (the role ServeEvents plays in serve)."""

    def __init__(self) -> None:
        self.next: list = []

    def update(self, people3d) -> list:
        out, self.next = self.next, []
        return out


class Run:
    """An IncidentStep as serve wires it, over the served log; `step(events)` one step."""

    def __init__(self, served, plan, resume: Resume | None = None, live: bool = False) -> None:
        self.served, self.script, self.t, self.frame = served, Script(), 0.0, 0
        self.ids = IncidentIds(served.out / "events.sqlite")
        book = IncidentBook(AlarmSettings.from_site(plan.site), next_id=self.ids)
        if resume is not None:
            book.restore(resume.open_incidents(WALL_START))
        self.changes: list = []
        outputs = [served.db.write_changes, self.changes.extend]
        if live:  # as serve wires the console's live channel
            outputs.append(served.console.hub.incident_changes)
        self.desk = IncidentStep(
            book,
            step_chain(self.script),
            outputs=outputs,
            clock=lambda: self.t,
            wall_start=WALL_START,
        )
        served.server.app.state.incidents.attach(self.desk)
        self.jsonl = JsonlSink(served.out / "events.jsonl")

    def step(self, events=(), t: float | None = None) -> list:
        self.frame += 1
        self.t = max(self.t, *(e.t for e in events)) if events else (t or self.t + 0.1)
        self.script.next = list(events)
        people = frame_result(self.frame, 0).people3d
        out, _ = self.desk.step(self.t, self.frame, people)
        self.served.db.write_events(out)
        self.jsonl.write_events(out)
        return out

    def close(self) -> None:
        self.ids.close()
        self.jsonl.close()


def _rows(served, sql: str, args=()) -> list[tuple]:
    db = sqlite3.connect(served.out / "events.sqlite")
    try:
        return db.execute(sql, args).fetchall()
    finally:
        db.close()


def _reaches(run: Run) -> None:
    """Person 7 reaches into the busbar three times; then a camera goes down."""
    for frame in (30, 60, 90):
        run.step([zone_event(frame, "enter")])
        run.step([zone_event(frame + 10, "exit")])
    run.step(
        [
            Event(
                t=200 / 30,
                frame=200,
                person=-1,
                zone="",
                kind="camera",
                type="camera_down",
                onset_t=200 / 30,
                camera="cam02",
            )
        ]
    )


def test_repeated_entries_one_incident_with_count_carried_by_events(tmp_path, plan):
    with console_server(tmp_path / "out", plan) as served:
        run = Run(served, plan)
        _reaches(run)
        rows = _rows(served, "SELECT type, person, incident, priority FROM events ORDER BY id")
        enters = [r for r in rows if r[0] == "enter" and r[1] == 7]
        assert len(enters) == 3 and len({r[2] for r in enters}) == 1
        busbar = enters[0][2]
        assert busbar is not None and enters[0][3] == 1  # an energized entry: critical
        inc = _rows(served, "SELECT occurrences FROM incidents WHERE id = ?", (busbar,))
        assert inc == [(3,)]  # one incident, three occurrences, stored once
        lines = [json.loads(x) for x in (served.out / "events.jsonl").read_text().splitlines()]
        assert all("incident" in d and "priority" in d for d in lines)
        assert [d["incident"] for d in lines if d["type"] == "enter" and d["person"] == 7] == [
            busbar
        ] * 3
        c = served.client("vera")
        found = c.get("/api/incidents").json()["incidents"]
        mine = [i for i in found if i["id"] == busbar]
        assert len(mine) == 1 and mine[0]["occurrences"] == 3
        assert mine[0]["first_wall_t"] == pytest.approx(WALL_START + 1.0)
        events = c.get("/api/events", params={"person": 7, "type": "enter"}).json()["events"]
        assert {e["incident"] for e in events} == {busbar}
        run.close()


def test_incident_filters(tmp_path, plan):
    with console_server(tmp_path / "out", plan) as served:
        run = Run(served, plan)
        _reaches(run)
        c = served.client("vera")

        def ids(**params) -> list[int]:
            r = c.get("/api/incidents", params=params)
            assert r.status_code == 200, r.text
            return [i["id"] for i in r.json()["incidents"]]

        every = ids()
        assert len(every) == 2 and every == sorted(every, reverse=True)
        assert ids(zone="overhead_busbar") == [every[1]]
        assert ids(person=7) == [every[1]]
        assert ids(priority=1) == [every[1]]
        assert ids(priority=4) == [every[0]]  # a camera's diagnostics: low
        assert ids(state="active") == [every[0]]  # the busbar's cleared at the last exit
        assert ids(state="cleared") == [every[1]]
        assert ids(limit=1) == [every[0]]
        assert ids(since=str(WALL_START + 6.0)) == [every[0]]
        assert ids(until=str(WALL_START + 2.0)) == [every[1]]
        assert c.get("/api/incidents", params={"state": "bogus"}).status_code == 422
        run.close()


def test_ack_and_shelve_reach_the_book_and_the_store(tmp_path, plan):
    with console_server(tmp_path / "out", plan) as served:
        run = Run(served, plan)
        _reaches(run)
        busbar, work = sorted(i.id for i in run.desk.book.incidents())
        viewer, operator = served.client("vera"), served.client("otto")
        assert viewer.post(f"/api/incidents/{busbar}/ack").status_code == 403
        assert operator.post("/api/incidents/999999/ack").status_code == 404
        r = operator.post(f"/api/incidents/{busbar}/ack")
        assert r.status_code == 200, r.text
        assert r.json()["incident"]["state"] == "closed"  # cleared, now acknowledged
        assert run.desk.book.get(busbar).acked_by == "otto"
        bad = [
            {"reason": "", "duration_s": 60},
            {"reason": "x", "duration_s": 0},
            {"reason": "x", "duration_s": 10 * 3600},
        ]
        for body in bad:
            got = operator.post(f"/api/incidents/{work}/shelve", json=body)
            assert got.status_code == 422, (body, got.text)
        assert (
            viewer.post(
                f"/api/incidents/{work}/shelve", json={"reason": "maintenance", "duration_s": 600}
            ).status_code
            == 403
        )
        r = operator.post(
            f"/api/incidents/{work}/shelve", json={"reason": "maintenance", "duration_s": 600}
        )
        assert r.status_code == 200, r.text
        assert r.json()["incident"]["shelved_by"] == "otto"
        assert run.desk.book.get(work).shelved
        run.step()  # the next step stores and publishes the operator's changes
        got = {i["id"]: i for i in viewer.get("/api/incidents").json()["incidents"]}
        assert got[busbar]["state"] == "closed" and got[busbar]["acked_by"] == "otto"
        assert got[busbar]["acked_wall_at"] is not None
        assert got[work]["shelved"] and got[work]["shelved_reason"] == "maintenance"
        assert got[work]["shelved_wall_until"] == pytest.approx(WALL_START + run.t + 600, abs=1)
        assert [c.what for c in run.changes][-2:] == ["acknowledged", "shelved"]
        run.close()


def test_event_ack_acknowledges_its_incident(tmp_path, plan):
    with console_server(tmp_path / "out", plan) as served:
        run = Run(served, plan)
        run.step([zone_event(30, "enter")])
        ((event_id, incident),) = _rows(served, "SELECT id, incident FROM events")
        r = served.client("otto").post(f"/api/events/{event_id}/ack")
        assert r.status_code == 200, r.text
        assert r.json()["incident"]["id"] == incident
        assert run.desk.book.get(incident).state == "acknowledged"
        run.step()
        wait_until(
            lambda: (
                _rows(served, "SELECT state FROM incidents WHERE id = ?", (incident,))
                == [("acknowledged",)]
            ),
            "the ack stored",
        )
        run.close()


def test_restart_restores_open_incidents_once_new_ids_above(tmp_path, plan):
    out = tmp_path / "out"
    with console_server(out, plan) as served:
        run = Run(served, plan)
        run.step([zone_event(30, "enter")])  # open: the person is still inside
        first = run.desk.book.incidents()[0].id
        run.close()
    resume = Resume.from_log(out / "events.sqlite")
    assert [r.id for r, _ in resume.incidents] == [first]
    with console_server(out, plan, users=False) as served:
        run = Run(served, plan, resume)
        assert [r.id for r in run.desk.book.incidents()] == [first]
        # the same person's next entry is an occurrence of the restored incident
        run.step([zone_event(90, "enter")])
        run.step([zone_event(120, "enter", 9)])
        ids = [r.id for r in run.desk.book.incidents()]
        assert ids[0] == first and len(ids) == 2 and ids[1] > first
        assert run.desk.book.get(first).occurrences == 2
        rows = _rows(served, "SELECT id FROM incidents ORDER BY id")
        assert [r[0] for r in rows] == ids  # stored once each
        run.close()


def test_alarm_rates_in_metrics(tmp_path, plan):
    with console_server(tmp_path / "out", plan) as served:
        run = Run(served, plan)
        served.state.register_alarms(run.desk.figures)
        _reaches(run)
        text = served.client().get("/metrics").text
        # two incidents raised (the busbar, the camera): two notifications in both windows
        assert 'stereopose_alarm_notifications{window="10m"} 2.0' in text
        assert 'stereopose_alarm_notifications{window="1h"} 2.0' in text
        assert "stereopose_alarm_flood 0.0" in text
        assert 'stereopose_incidents_open{priority="1",state="cleared"} 1.0' in text
        assert 'stereopose_incidents_open{priority="4",state="active"} 1.0' in text
        figures = run.desk.figures()
        assert figures["notifications_10min"] == 2 and figures["open"] == {
            "p1_cleared": 1,
            "p4_active": 1,
        }
        # the console's alarm-rate panel: the same figures, for a logged-in user only
        assert served.client().get("/api/alarm-rates").status_code == 401
        rates = served.client("vera").get("/api/alarm-rates").json()
        assert rates["running"] is True and rates["notifications_10min"] == 2
        assert rates["flood_line"] == 10 and rates["shelved"] == 0
        assert served.client().get("/api/health").json()["alarms"] is None
        health = served.client("vera").get("/api/health").json()
        assert health["alarms"]["notifications_1h"] == 2
        camera = next(i.id for i in run.desk.book.incidents() if i.camera)
        served.client("otto").post(
            f"/api/incidents/{camera}/shelve", json={"reason": "lens cleaned", "duration_s": 60}
        )
        assert served.client("vera").get("/api/alarm-rates").json()["shelved"] == 1
        assert "stereopose_alarm_shelved 1.0" in served.client().get("/metrics").text
        run.close()


def test_alarm_rates_before_the_book_runs(tmp_path, plan):
    with console_server(tmp_path / "out", plan) as served:
        assert served.client("vera").get("/api/alarm-rates").json() == {"running": False}


def test_the_live_channel_pushes_each_incident_change(tmp_path, plan):
    with console_server(tmp_path / "out", plan) as served:
        run = Run(served, plan, live=True)
        c, otto = served.client("vera"), served.client("otto")
        try:
            live = _Stream(c)
            live.next("cameras", 10)
            run.step([zone_event(30, "enter")])
            raised = live.next("incident", 5)
            assert raised["change"] == "raised" and raised["notify"] is True
            # on the wall clock too, as the console shows it
            assert raised["wall_t"] == pytest.approx(WALL_START + 1.0)
            assert raised["incident"]["first_wall_t"] == pytest.approx(WALL_START + 1.0)
            incident = raised["incident"]["id"]
            event = live.next("event", 5)
            assert event["incident"] == incident and event["priority"] == 1
            run.step([zone_event(40, "enter")])  # the same hazard: an occurrence, no notify
            again = live.next("incident", 5)
            assert again["change"] == "occurrence" and not again["notify"]
            assert again["incident"]["occurrences"] == 2
            otto.post(f"/api/incidents/{incident}/ack").raise_for_status()
            run.step()
            acked = live.next("incident", 5)
            assert acked["change"] == "acknowledged" and acked["by"] == "otto"
            assert acked["incident"]["acked_wall_at"] == pytest.approx(WALL_START + run.t)
        finally:
            c.close()
            otto.close()
            run.close()
