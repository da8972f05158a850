"""`stereopose reconstruct` on a small simulated scene with a site holding [[rules]]: postures in
the 3D poses, behaviour events in the JSON lines, the SQLite log and at a webhook."""

from __future__ import annotations

import json
from pathlib import Path

from receivers import Receiver
from stereopose.behaviour import POSTURES, UNKNOWN
from stereopose.cli import main
from stereopose.io.sinks.events import query_events
from waiting import wait_until

SITE = """
fps = 25.0
[[zones]]
name = "hall"
kind = "restricted"
polygon = [[-20.0, -20.0], [20.0, -20.0], [20.0, 20.0], [-20.0, 20.0]]
z = [0.0, 3.0]

# every wrist is above 0.5 m: each person overreaches 0.2 s after they are first seen
[[rules]]
name = "low_bar"
type = "overreach"
max_height_m = 0.5

[[rules]]
name = "man_down"
type = "person_down"
"""


def test_reconstruct_with_rules_writes_postures_and_behaviour_events(
    tmp_path: Path, capsys
) -> None:
    scene = tmp_path / "scene"
    args = [
        "--frames",
        "40",
        "--cameras",
        "3",
        "--people",
        "2",
        "--difficulty",
        "easy",
        "--seed",
        "5",
    ]
    assert main(["simulate", str(scene), *args]) == 0
    site = tmp_path / "site.toml"
    site.write_text(SITE)
    out, events, db = tmp_path / "poses.jsonl", tmp_path / "events.jsonl", tmp_path / "e.sqlite"
    receiver = Receiver()
    try:
        rc = main(
            [
                "reconstruct",
                "--calib",
                str(scene / "calib.toml"),
                "--pose",
                str(scene / "pose"),
                "--out",
                str(out),
                "--site",
                str(site),
                "--events",
                str(events),
                "--events-db",
                str(db),
                "--webhook",
                receiver.url,
            ]
        )
        assert rc == 0, capsys.readouterr().err
        frames = [json.loads(line) for line in out.read_text().splitlines()]
        people = [p for f in frames for p in f["people"]]
        assert len(frames) == 40 and people
        assert all(p["posture"] in (*POSTURES, UNKNOWN) for p in people)
        assert all(isinstance(p["flags"], list) for p in people)
        # simulated workers walk and stand; none falls, crouches or lies
        upright = sum(p["posture"] in ("standing", "walking", "bending") for p in people)
        assert upright >= 0.95 * len(people)
        ids = {p["id"] for p in people}
        evs = [json.loads(line) for line in events.read_text().splitlines()]
        over = [e for e in evs if e.get("rule") == "low_bar"]
        assert {e["person"] for e in over} == ids and {e["type"] for e in over} == {"overreach"}
        assert all(e["kind"] == "behaviour" and e["height_m"] > 0.5 for e in over)
        assert not [e for e in evs if e.get("rule") == "man_down"]
        first_seen = {}
        for f in frames:
            for p in f["people"]:
                first_seen.setdefault(p["id"], f["t"])
        for e in over:  # raised enter_s (0.2 s) after the person first appeared
            assert abs(e["onset_t"] - first_seen[e["person"]]) < 1e-6
            assert abs(e["t"] - e["onset_t"] - 0.2) < 1e-6
        rows = query_events(db, event_type="overreach")
        assert sorted(r["person"] for r in rows) == sorted(e["person"] for e in over)
        assert {r["rule"] for r in rows} == {"low_bar"}
        wait_until(lambda: len(receiver.bodies) == len(evs), "every event at the webhook")
        assert {b["rule"] for b in receiver.bodies if b["kind"] == "behaviour"} == {"low_bar"}
    finally:
        receiver.close()
