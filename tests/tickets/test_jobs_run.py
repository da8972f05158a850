"""Simulated jobs through the real pipeline (`reconstruct --ticket`: triangulation, tracking,
fences, the incident book): each variant's deviations found, none on a compliant job, and
the isolated panel's entries info while its live neighbour's stay alarms."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from stereopose.cli import main
from stereopose.fence.site import save_site
from stereopose.sim.io import write_scene
from stereopose.sim.jobs import VARIANTS, simulate_job

DEVIATIONS = {
    "step_out_of_order",
    "step_wrong_position",
    "step_timeout",
    "supervisor_absent",
    "lone_in_room",
}


def _ticket_toml(ticket) -> str:
    lines = [
        f'id = "{ticket.id}"',
        f'title = "{ticket.title}"',
        f'kind = "{ticket.kind}"',
        f"isolated = {json.dumps(list(ticket.isolated))}",
        f"supervise_m = {ticket.supervise_m}",
        f"absent_s = {ticket.absent_s}",
        "lone_s = false",
        "[roles]",
        'operator = "auto"',
    ]
    if ticket.supervisor is not None:
        lines.append('supervisor = "auto"')
    for s in ticket.steps:
        lines += [
            "[[steps]]",
            f'name = "{s.name}"',
            f'position = "{s.position}"',
            f'target = "{s.target}"',
            f"hold_s = {s.hold_s}",
            f"max_s = {s.max_s}",
        ]
    return "\n".join(lines) + "\n"


def run_job(tmp_path: Path, variant: str, ticket: bool = True) -> list[dict]:
    js = simulate_job(variant, seed=1, difficulty="easy")
    write_scene(js.scene, tmp_path / "scene")
    save_site(tmp_path / "site.toml", js.site)
    (tmp_path / "ticket.toml").write_text(_ticket_toml(js.ticket))
    args = [
        "reconstruct",
        "--calib",
        str(tmp_path / "scene" / "calib.toml"),
        "--pose",
        str(tmp_path / "scene" / "pose"),
        "--out",
        str(tmp_path / "poses.jsonl"),
        "--site",
        str(tmp_path / "site.toml"),
        "--events",
        str(tmp_path / "events.jsonl"),
        "--fps",
        "25",
    ]
    if ticket:
        args += ["--ticket", str(tmp_path / "ticket.toml")]
    assert main(args) == 0
    events = [json.loads(x) for x in (tmp_path / "events.jsonl").read_text().splitlines()]
    return events, js


@pytest.mark.parametrize("variant", VARIANTS)
def test_each_job_s_deviations_are_found_and_none_more(tmp_path: Path, variant: str) -> None:
    events, js = run_job(tmp_path, variant)
    found = sorted((e["type"], e.get("step")) for e in events if e["type"] in DEVIATIONS)
    assert found == sorted(js.deviations)
    done = [e["step"] for e in events if e["type"] == "step_done"]
    assert done == list(js.steps_done)
    for e in events:
        if e["type"] in DEVIATIONS:  # an alarm: through the incident book, with a priority
            assert e["ticket"] == js.ticket.id and e["incident"] and e["priority"]
    completed = [e for e in events if e["type"] == "ticket_completed"]
    assert len(completed) == 1
    result = completed[0]["result"]
    assert sorted(result["done"]) == sorted(js.steps_done)  # in the ticket's order
    assert result["deviations"] == len(js.deviations)
    missed = [s.name for s in js.ticket.steps if s.name not in js.steps_done]
    assert result["missed"] == missed


def test_the_isolated_panel_is_info_and_its_live_neighbour_an_alarm(tmp_path: Path) -> None:
    events, js = run_job(tmp_path / "with", "neighbour_live")
    alarms = {e["zone"] for e in events if e["kind"] == "energized" and e["incident"]}
    assert alarms == set(js.live_touches)  # bay 3 only
    isolated = [e for e in events if e["kind"] == "isolated"]
    assert isolated and all(e["zone"] == "bay2_panel" and e["incident"] is None for e in isolated)
    assert all(e["ticket"] == js.ticket.id for e in isolated)
    # without the ticket, the same job's touches of the isolated panel are alarms
    before, _ = run_job(tmp_path / "without", "neighbour_live", ticket=False)
    alarms = {e["zone"] for e in before if e["kind"] == "energized" and e["incident"]}
    assert alarms == {"bay2_panel", "bay3_panel"}
