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
