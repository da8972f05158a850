"""Carried steps (detection.carry): which cameras skip the detector, and what they carry."""

from __future__ import annotations

import itertools
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from stereopose.config import DetectorConfig
from stereopose.detection.carry import Carrier, CarrySettings, carrier
from stereopose.types import People2D

DT = 1 / 60


def person(x: float, y: float = 100.0, height: float = 400.0, hand: float = 0.0) -> np.ndarray:
    """A standing person's 17 joints (x, y, conf) at (x, y), `height` px tall; the right
    wrist (10) moved `hand` px to the right."""
    ys = np.linspace(y, y + height, 17)
    kp = np.column_stack([np.full(17, x), ys, np.full(17, 0.9)])
    kp[10, 0] += hand
    return kp


def people(camera: str, frame: int, *kps: np.ndarray) -> People2D:
    kp = np.array(kps, float).reshape(-1, 17, 3)
    boxes = [[p[:, 0].min() - 50, p[:, 1].min(), p[:, 0].max() + 50, p[:, 1].max()] for p in kp]
    return People2D(camera, frame, kp, np.array(boxes).reshape(-1, 4), np.full(len(kp), 0.8))


def drive(carry: Carrier, names, steps: int, found) -> list[set[str]]:
    """`steps` steps of `names`: each step's carried cameras; found(name, step): what the
    detector finds in a camera it runs on."""
    out = []
    for step in range(steps):
        t = step * DT
        skip = carry.plan(list(names), step, t)
        for name in names:
            if name in skip:
                carry.carried(name, step)
            else:
                carry.seen(name, found(name, step), step, t)
        out.append(skip)
    return out


def test_still_cameras_take_turns_and_none_is_carried_twice_in_a_row():
    names = ["cam01", "cam02", "cam03", "cam04"]
    carry = Carrier()
    plans = drive(carry, names, 40, lambda n, s: people(n, s, person(500 + 0.5 * s)))
    assert plans[:2] == [set(), set()]  # two detections first
    for a, b in itertools.pairwise(plans[2:]):
        assert len(a) == 2 and not a & b  # half the cameras, never the same two in a row
    report = carry.report()
    assert sum(c["carried"] for c in report.values()) == sum(len(p) for p in plans)
    assert all(c["detected"] + c["carried"] == 40 for c in report.values())


def test_a_hand_that_reaches_out_is_detected_at_every_step():
    """The body stands still but the right wrist moves 30 px a step (over 5 % of 400 px)."""
    carry = Carrier()
    plans = drive(carry, ["cam01"], 20, lambda n, s: people(n, s, person(500, hand=30.0 * s)))
    assert not any(plans)
    # a doubted joint's jumps do not count
    carry = Carrier()

    def doubted(n, s):
        kp = person(500, hand=30.0 * s)
        kp[10, 2] = 0.2
        return people(n, s, kp)

    assert any(drive(carry, ["cam01"], 20, doubted))


def test_a_walk_past_the_camera_and_a_newcomer_are_detected_at_every_step():
    fast = Carrier(CarrySettings(motion=0.05))
    assert not any(drive(fast, ["cam01"], 20, lambda n, s: people(n, s, person(500 + 25.0 * s))))
    slow = Carrier(CarrySettings(motion=0.1))  # 25 px of 400 is within a tenth
    assert any(drive(slow, ["cam01"], 20, lambda n, s: people(n, s, person(500 + 25.0 * s))))
    # one more person at every other detection: never the same people twice, never carried
    newcomer = Carrier()

    def coming(n, s):
        return people(n, s, *[person(300 + 200 * k) for k in range(1 + s % 2)])

    assert not any(drive(newcomer, ["cam01"], 20, coming))


def test_a_carried_camera_gives_its_last_detection_at_the_step_carried():
    carry = Carrier()
    names = ["cam01", "cam02"]
    last: dict[str, People2D] = {}

    def found(n, s):
        last[n] = people(n, s, person(400 + s), person(900 - s))
        return last[n]

    for step in range(6):
        skip = carry.plan(names, step, step * DT)
        for name in names:
            if name in skip:
                got = carry.carried(name, step)
                assert got.camera == name and got.frame == step
                np.testing.assert_array_equal(got.keypoints, last[name].keypoints)
                np.testing.assert_array_equal(got.boxes, last[name].boxes)
            else:
                carry.seen(name, found(name, step), step, step * DT)
    assert carry.report()["cam01"]["carried"] > 0


def test_an_empty_camera_is_carried_and_a_missed_step_starts_again():
    carry = Carrier()
    plans = drive(carry, ["cam01"], 6, lambda n, s: people(n, s))
    assert any(plans)
    assert len(carry.carried("cam01", 99)) == 0
    # the camera had no picture at the step before: it is not carried
    carry.seen("cam01", people("cam01", 10), 10, 10 * DT)
    assert carry.plan(["cam01"], 12, 12 * DT) == set()


def test_the_settings_and_the_configuration():
    with pytest.raises(ValueError, match="carry motion"):
        CarrySettings(motion=0.0)
    assert carrier(DetectorConfig(carry=False)) is None
    assert carrier(DetectorConfig(carry_motion=0.2)).settings.motion == 0.2


def _events(folder) -> list[dict]:
    return [json.loads(line) for line in (folder / "events.jsonl").read_text().splitlines()]


BUSBAR_POLYGON = "polygon = [[-1.0, -0.45], [-0.45, -0.45], [-0.45, 0.0], [-1.0, 0.0]]"


def _run_demo(real_demo_dir: Path, out: Path, detector: str = "", site=None, ticket=True) -> dict:
    """The real demo's run again into `out`, with [detector] lines added and `site` (the
    text of its site file; None: the demo's); its summary."""
    from stereopose.cli import main

    for name in ("demo_site.toml", "demo_ticket.toml"):
        shutil.copy(real_demo_dir / name, out / name)
    if site is not None:
        (out / "demo_site.toml").write_text(site)
    config = out / "demo.toml"
    config.write_text((real_demo_dir / "demo.toml").read_text() + f"\n[detector]\n{detector}\n")
    args = ["run", str(config)] + (["--ticket", str(out / "demo_ticket.toml")] if ticket else [])
    assert main(args) == 0
    return json.loads((out / "summary.json").read_text())


def test_carried_steps_keep_every_alarm_of_the_real_demo(real_demo_dir: Path, tmp_path: Path):
    """The demo (carried steps on, the default) against the same run with every camera
    detected at every step: every alarm of the one is in the other, for the same person, zone
    and type, at most one step apart; the joints reproject as well (+0.5 px at most). The
    walker works at the busbar: the cameras that see him there detect at every step."""
    carried = json.loads((real_demo_dir / "summary.json").read_text())
    frames = carried["frames"]
    assert all(c["detected"] + c["carried"] == frames for c in carried["carry"].values())
    assert sum(c["near_hazard"] for c in carried["carry"].values()) >= 0.1 * 4 * frames
    every = _run_demo(real_demo_dir, tmp_path, "carry = false")
    assert "carry" not in every
    alarms = [e for e in _events(tmp_path) if e["kind"] == "energized"]
    assert {e["type"] for e in alarms} >= {"approach", "enter", "exit"}
    kept = _events(real_demo_dir)
    for a in alarms:
        same = [
            e
            for e in kept
            if (e["person"], e["zone"], e["kind"], e["type"])
            == (a["person"], a["zone"], a["kind"], a["type"])
            and abs(e["frame"] - a["frame"]) <= 1
        ]
        assert same, f"alarm {a} of the run detected at every step is not kept"
    assert carried["reprojection_median_px"] <= every["reprojection_median_px"] + 0.5


def test_the_demo_is_carried_with_its_busbar_moved_away_and_held_with_it_back(
    real_demo_dir: Path, tmp_path: Path
):
    """The demo's frames with the busbar moved 50 m away: nobody is near a hazard, and the
    slow steps are carried (a tenth of them at least); with the busbar back where the walker
    reaches into it (the demo), its cameras are held, and fewer steps are carried."""
    site = (real_demo_dir / "demo_site.toml").read_text()
    assert BUSBAR_POLYGON in site
    away = site.replace(
        BUSBAR_POLYGON, "polygon = [[49.0, -0.45], [49.55, -0.45], [49.55, 0.0], [49.0, 0.0]]"
    )
    moved = _run_demo(real_demo_dir, tmp_path, site=away, ticket=False)
    assert not [e for e in _events(tmp_path) if e["zone"] == "overhead_busbar"]
    frames = moved["frames"]
    carried_away = sum(c["carried"] for c in moved["carry"].values())
    assert sum(c["near_hazard"] for c in moved["carry"].values()) == 0
    assert carried_away >= 0.1 * 4 * frames
    back = json.loads((real_demo_dir / "summary.json").read_text())["carry"]
    assert sum(c["near_hazard"] for c in back.values()) > 0
    assert sum(c["carried"] for c in back.values()) < carried_away / 2


def test_a_camera_that_sees_someone_near_a_hazard_is_never_carried():
    """`hold` (the cameras seeing someone near an energized zone) detects at every step, and
    counts the steps it would have been carried; the others still take their turns."""
    names = ["cam01", "cam02"]
    carry = Carrier()
    plans = []
    for step in range(20):
        t = step * DT
        hold = {"cam01"} if step < 12 else set()
        skip = carry.plan(names, step, t, hold)
        for name in names:
            if name in skip:
                carry.carried(name, step)
            else:
                carry.seen(name, people(name, step, person(500)), step, t)
        plans.append(skip)
    assert not any("cam01" in p for p in plans[:12])
    assert any("cam01" in p for p in plans[12:])  # far from it again: carried again
    assert any("cam02" in p for p in plans[:12])
    report = carry.report()
    assert report["cam01"]["near_hazard"] == 5  # its turns at steps 3, 5, ..., 11
    assert report["cam02"]["near_hazard"] == 0
    assert report["cam01"]["detected"] + report["cam01"]["carried"] == 20


def test_who_is_near_a_hazard_is_asked_only_for_the_cameras_that_would_be_carried():
    """`hold` as a function: asked at a step only when some camera would be carried, and only
    about those (finding who is near a hazard costs a millisecond a step); what it names is
    held as a set would be."""
    names = ["cam01", "cam02"]
    carry = Carrier()
    asked: list[list[str]] = []

    def hold(ready: list[str]) -> set[str]:
        asked.append(list(ready))
        return {"cam01"}

    carried = []
    for step in range(12):
        t = step * DT
        skip = carry.plan(names, step, t, hold)
        carried.append(skip)
        for name in names:
            if name in skip:
                carry.carried(name, step)
            else:
                carry.seen(name, people(name, step, person(500)), step, t)
    assert asked and len(asked) < 12  # not at the first steps (nothing slow yet), nor every
    assert all(len(a) == 1 for a in asked)  # the cameras take turns: one ready at a step
    assert not any("cam01" in s for s in carried)
    assert any("cam02" in s for s in carried)
    assert carry.report()["cam01"]["near_hazard"] == sum(a == ["cam01"] for a in asked)
