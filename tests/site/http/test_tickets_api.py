"""The tickets API on a real server: a ticket posted, started and ended by an operator (a
viewer refused), bad tickets and acts answered with their problem, and the ticket followed
through the service's incident step (the step serve wires) over a simulated job."""

from __future__ import annotations

from pathlib import Path

from consoled import console_server
from stereopose.alarms import IncidentBook
from stereopose.alarms.priority import AlarmSettings
from stereopose.fence import FenceMonitor
from stereopose.pipeline.incidents import IncidentStep
from stereopose.sim.behaviour_events import truth_frames
from stereopose.sim.jobs import simulate_job
from stereopose.site.desk import IncidentDesk
from stereopose.tickets import TicketDesk


def test_a_ticket_started_over_the_api_is_followed_step_by_step(tmp_path: Path) -> None:
    js = simulate_job("swapped", seed=3)
    site, fps = js.site, js.scene.fps
    desk, incidents = TicketDesk(site.zones), IncidentDesk()
    fences = FenceMonitor(site, fps)
    now = [0.0]
    step = IncidentStep(
        IncidentBook(AlarmSettings.from_site(site)),
        fences,
        None,
        fences,
        clock=lambda: now[0],
        tickets=desk,
    )
    incidents.attach(step)
    body = js.ticket.to_dict()
    with console_server(
        tmp_path, app_kw={"tickets": desk, "incidents": incidents}, events=False
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
            raised += [e for e in events if e.kind == "ticket"]
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
