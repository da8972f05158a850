"""The tickets API on a real server: a ticket posted (JSON or its TOML file), started and ended
by an operator (a viewer refused), bad tickets and acts answered with their problem, the ticket
followed through the service's incident step (the step serve wires) over a simulated job whose
3D poses go into the service's pose segments, then its report and the 3D replay of its steps
read back from those segments."""

from __future__ import annotations

from pathlib import Path

from consoled import WALL_START, console_server
from stereopose.alarms import IncidentBook
from stereopose.alarms.priority import AlarmSettings
from stereopose.fence import FenceMonitor
from stereopose.io.sinks.base import FrameResult
from stereopose.io.sinks.segments import SegmentSink
from stereopose.pipeline.incidents import IncidentStep
from stereopose.pipeline.step_rules import step_chain
from stereopose.sim.behaviour_events import truth_frames
from stereopose.sim.jobs import simulate_job
from stereopose.site.desk import IncidentDesk
from stereopose.site.http.app import Desks
from stereopose.tickets import TicketDesk


def test_a_ticket_started_over_the_api_is_followed_step_by_step(tmp_path: Path) -> None:
    js = simulate_job("swapped", seed=3)
    site, fps = js.site, js.scene.fps
    desk, incidents = TicketDesk(site.zones), IncidentDesk()
    fences = FenceMonitor(site, fps)
    now = [0.0]
    step = IncidentStep(
        IncidentBook(AlarmSettings.from_site(site)),
        step_chain(fences, tickets=desk),
        holding=fences,
        clock=lambda: now[0],
    )
    incidents.attach(step)
    desk.wall_start = WALL_START
    segments = SegmentSink(tmp_path, fps, wall_start=WALL_START)
    body = js.ticket.to_dict()
    with console_server(
        tmp_path, app_kw={"desks": Desks(tickets=desk, incidents=incidents)}, events=False
    ) as served:
        viewer, op = served.client("vera"), served.client("otto")
        assert viewer.post("/api/tickets", json=body).status_code == 403
        r = op.post("/api/tickets", json=body)
        assert r.status_code == 201 and r.json()["ticket"]["state"] == "planned"
        assert op.post("/api/tickets", json=body).status_code == 409  # the id is taken
        bad = op.post("/api/tickets", json={**body, "id": "X", "steps": [{"name": "a"}]})
        assert bad.status_code == 400 and "position" in bad.json()["detail"]
        elsewhere = {**body, "id": "Y", "isolated": ["bay9_panel"]}
        assert "bay9_panel" in op.post("/api/tickets", json=elsewhere).json()["detail"]
        assert op.post("/api/tickets/nope/start").status_code == 404
        r = op.post(f"/api/tickets/{js.ticket.id}/start")
        assert r.status_code == 200 and r.json()["ticket"]["starting"]
        assert op.post(f"/api/tickets/{js.ticket.id}/start").status_code == 409
        raised = []
        for people in truth_frames(js.scene):
            now[0] = people.frame / fps
            events, _ = step.step(now[0], people.frame, people)
            segments.write(FrameResult(people.frame, now[0], {}, people, events))
            raised += [e for e in events if e.kind == "ticket"]
        segments.close()
        got = viewer.get(f"/api/tickets/{js.ticket.id}").json()["ticket"]
        assert got["state"] == "active" and got["steps_done"] == 3 and got["deviations"] == 1
        assert [s["state"] for s in got["steps"]] == ["done"] * 3
        assert [s["in_order"] for s in got["steps"]] == [True, True, False]
        wrong = [e for e in raised if e.type == "step_out_of_order"]
        assert len(wrong) == 1 and wrong[0].incident is not None  # an incident of the book
        assert op.post(f"/api/tickets/{js.ticket.id}/end", json={}).json()["ticket"]["ending"]
        events, _ = step.step(now[0] + 0.04, people.frame + 1, people)
        assert [e.type for e in events if e.kind == "ticket"] == ["ticket_completed"]
        listed = viewer.get("/api/tickets").json()["tickets"]
        assert [(t["id"], t["state"]) for t in listed] == [(js.ticket.id, "completed")]
        assert op.post(f"/api/tickets/{js.ticket.id}/end").status_code == 409
        ended = viewer.get(f"/api/tickets/{js.ticket.id}").json()["ticket"]
        _replays_and_reports(viewer, ended, js, duration=now[0])


def _replays_and_reports(viewer, ended: dict, js, duration: float) -> None:
    """Each step's 3D replay holds the operator's action; the job's report names every step,
    the deviation and draws the job in 3D; a window that is not one is refused."""
    assert ended["started_wall"] == WALL_START + ended["started_t"]
    for s in ended["steps"]:
        since, until = s["onset_wall"] - 1.0, s["done_wall"] + 1.0
        r = viewer.get("/api/poses", params={"since": since, "until": until})
        assert r.status_code == 200
        frames = r.json()["frames"]
        assert frames and all(since <= f["wall_t"] <= until for f in frames)
        ids = {p["id"] for f in frames for p in f["people"]}
        assert s["by"] in ids and all(len(p["joints"]) == 17 for f in frames for p in f["people"])
    whole = viewer.get(
        "/api/poses",
        params={"since": WALL_START, "until": WALL_START + duration, "max_frames": 20},
    ).json()
    assert len(whole["frames"]) == 20 and whole["thinned"]
    times = [f["wall_t"] for f in whole["frames"]]
    assert times == sorted(times)
    assert viewer.get("/api/poses", params={"since": 10, "until": 5}).status_code == 400
    assert viewer.get("/api/poses", params={"since": 0, "until": 10**6}).status_code == 400
    empty = viewer.get("/api/poses", params={"since": 100, "until": 200}).json()
    assert empty["frames"] == []
    r = viewer.get(f"/api/tickets/{js.ticket.id}/report")
    assert r.status_code == 200 and r.headers["content-type"].startswith("text/html")
    assert "attachment" in r.headers["content-disposition"]
    page = r.text
    assert all(s.name in page for s in js.ticket.steps)
    assert "step_out_of_order" in page and 'id="replay"' in page
    assert viewer.get("/api/tickets/nope/report").status_code == 404


def test_a_ticket_posted_as_its_toml_file(tmp_path: Path) -> None:
    js = simulate_job("compliant", seed=1)
    desk = TicketDesk(js.site.zones)
    text = (
        'id = "OT-T1"\ntitle = "by file"\nkind = "operation"\n[roles]\noperator = "auto"\n'
        f'[[steps]]\nname = "one"\nposition = "{js.ticket.steps[0].position}"\n'
        f'target = "{js.ticket.steps[0].target}"\n'
    )
    toml = {"Content-Type": "application/toml"}
    with console_server(tmp_path, app_kw={"desks": Desks(tickets=desk)}, events=False) as served:
        op = served.client("otto")
        r = op.post("/api/tickets", content=text.encode(), headers=toml)
        assert r.status_code == 201 and r.json()["ticket"]["id"] == "OT-T1"
        assert r.json()["ticket"]["steps"][0]["name"] == "one"
        bad = op.post("/api/tickets", content=b'id = "x\n', headers=toml)
        assert bad.status_code == 400 and "invalid TOML" in bad.json()["detail"]
        other = op.post("/api/tickets", content=b"<x/>", headers={"Content-Type": "text/xml"})
        assert other.status_code == 415
        binary = op.post("/api/tickets", content=b"\xff\xfe", headers=toml)
        assert binary.status_code == 400
        listed = op.post(
            "/api/tickets", content=b"[1, 2]", headers={"Content-Type": "application/json"}
        )
        assert listed.status_code == 400 and "object" in listed.json()["detail"]
