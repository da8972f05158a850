"""The demo site's behaviour rules raise their alarms on the real demo's detections, played
forward then backward as `serve --demo` loops the recording."""

from __future__ import annotations

import json
import re
from importlib import resources
from pathlib import Path

import pytest

from stereopose.cli import main

pytestmark = pytest.mark.realdata


def _looped(pose: Path, out: Path, rounds: int = 5) -> Path:
    """The keypoint folders of `pose` played forward, backward, forward ... (frames renumbered)."""
    for folder in sorted(p for p in pose.iterdir() if p.is_dir()):
        files = sorted(folder.iterdir(), key=lambda f: int(re.findall(r"\d+", f.name)[-1]))
        frames: list[Path] = []
        for k in range(rounds):
            frames += files if k % 2 == 0 else files[::-1][1:-1]
        (out / folder.name).mkdir(parents=True)
        for i, f in enumerate(frames):
            (out / folder.name / f"{folder.name[:-5]}_{i:012d}_keypoints.json").symlink_to(f)
    return out


def test_the_demo_site_raises_a_work_position_and_a_lone_worker_alarm(shared_data_dir, tmp_path):
    site = tmp_path / "demo_site.toml"
    site.write_text((resources.files("stereopose") / "data" / "demo_site.toml").read_text())
    pose = _looped(shared_data_dir / "pose", tmp_path / "pose")
    events = tmp_path / "events.jsonl"
    rc = main(
        [
            "reconstruct",
            "--calib",
            str(shared_data_dir / "calib.toml"),
            "--pose",
            str(pose),
            "--out",
            str(tmp_path / "poses.jsonl"),
            "--fps",
            "60",
            "--site",
            str(site),
            "--events",
            str(events),
        ]
    )
    assert rc == 0
    raised = {
        (e["rule"], e["type"])
        for e in map(json.loads, events.read_text().splitlines())
        if e["kind"] == "behaviour"
    }
    assert ("reach_from_work_area", "work_position") in raised
    assert ("alone_at_busbar", "lone_worker") in raised


@pytest.mark.parametrize("rounds", [1, 5])
def test_the_demo_recording_follows_the_demo_ticket(shared_data_dir, tmp_path, rounds):
    """The walker opens QS1 then closes QE1 from their front, the man on the treadmill beside
    him: both steps done in order, no deviation, played once (`make demo`) or looped (`serve
    --demo`)."""
    data = resources.files("stereopose") / "data"
    site = tmp_path / "demo_site.toml"
    site.write_text((data / "demo_site.toml").read_text())
    ticket = tmp_path / "demo_ticket.toml"
    ticket.write_text((data / "demo_ticket.toml").read_text())
    pose = _looped(shared_data_dir / "pose", tmp_path / "pose", rounds)
    events = tmp_path / "events.jsonl"
    argv = ["reconstruct", "--calib", str(shared_data_dir / "calib.toml"), "--pose", str(pose)]
    argv += ["--out", str(tmp_path / "poses.jsonl"), "--fps", "60", "--site", str(site)]
    argv += ["--events", str(events), "--ticket", str(ticket)]
    assert main(argv) == 0
    ticket_events = [
        e for e in map(json.loads, events.read_text().splitlines()) if e["kind"] == "ticket"
    ]
    done = [e["step"] for e in ticket_events if e["type"] == "step_done"]
    assert done == ["open isolator QS1", "test busbar dead"]
    deviations = {"step_out_of_order", "step_wrong_position", "step_timeout"}
    assert not [e for e in ticket_events if e["type"] in deviations | {"supervisor_absent"}]
    (completed,) = [e for e in ticket_events if e["type"] == "ticket_completed"]
    result = completed["result"]
    assert result["done_in_order"] == done and result["missed"] == [] and result["deviations"] == 0
    assert result["operator"] != result["supervisor"] and result["supervisor"] is not None
