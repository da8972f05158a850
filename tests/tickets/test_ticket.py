"""The ticket file: read as documented, every problem a ConfigError naming the file."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from stereopose.errors import ConfigError
from stereopose.sim.jobs import job_site
from stereopose.tickets import TicketDesk, load_ticket
from stereopose.tickets.desk import TicketError
from stereopose.tickets.ticket import check_zones
from stereopose.types import People3D

GOOD = """
id = "OT-0142"
title = "Bay 3: from service to maintenance"
kind = "operation"
isolated = []
supervise_m = 3.0
absent_s = 10.0
[roles]
operator = "auto"
supervisor = "auto"
[[steps]]
name = "open breaker QF3"
position = "bay3_front"
target = "bay3_handle"
hold_s = 1.0
max_s = 300.0
optional = false
[[steps]]
name = "earth"
position = "bay3_front"
target = "bay3_handle"
facing_deg = -90
posture = ["standing", "bending"]
both_hands = true
"""


def test_the_documented_ticket_is_read(tmp_path: Path) -> None:
    (tmp_path / "t.toml").write_text(GOOD)
    t = load_ticket(tmp_path / "t.toml")
    assert t.id == "OT-0142" and t.kind == "operation" and t.supervisor == "auto"
    assert [s.name for s in t.steps] == ["open breaker QF3", "earth"]
    assert t.steps[1].posture == ("standing", "bending") and t.steps[1].both_hands
    check_zones(t, {z.name: z.kind for z in job_site().zones})


@pytest.mark.parametrize(
    ("text", "says"),
    [
        ("id = 'x'\nsteps = []\n", "steps"),
        (GOOD.replace('kind = "operation"', 'kind = "maybe"'), "kind"),
        (GOOD.replace("hold_s = 1.0", "hold_s = -1"), "hold_s"),
        (GOOD.replace("hold_s = 1.0", "hold_s = nan"), "hold_s"),
        (GOOD.replace('name = "earth"', 'name = "open breaker QF3"'), "given twice"),
        (GOOD.replace("optional = false", "colour = 1"), "colour"),
        (GOOD.replace('supervisor = "auto"', 'supervisor = "bob"'), "roles.supervisor"),
        ("id = [", "not a valid TOML"),
    ],
)
def test_a_bad_ticket_names_the_file_and_the_problem(tmp_path: Path, text: str, says: str):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(ConfigError) as e:
        load_ticket(path)
    assert str(path) in str(e.value) and says in str(e.value)


def test_a_ticket_naming_an_unknown_or_live_zone_is_refused(tmp_path: Path) -> None:
    (tmp_path / "t.toml").write_text(GOOD.replace("bay3_handle", "nowhere", 1))
    zones = {z.name: z.kind for z in job_site().zones}
    with pytest.raises(ConfigError, match="'nowhere' not in the site file"):
        check_zones(load_ticket(tmp_path / "t.toml"), zones)
    (tmp_path / "u.toml").write_text(GOOD.replace("isolated = []", 'isolated = ["bay3_front"]'))
    with pytest.raises(ConfigError, match="not energized"):
        check_zones(load_ticket(tmp_path / "u.toml"), zones)


def test_the_desk_s_lifecycle(tmp_path: Path) -> None:
    (tmp_path / "t.toml").write_text(GOOD)
    desk = TicketDesk(job_site().zones)
    t = load_ticket(tmp_path / "t.toml")
    assert desk.add(t)["state"] == "planned"
    with pytest.raises(TicketError, match="exists already"):
        desk.add(t)
    with pytest.raises(TicketError) as e:
        desk.start("nope")
    assert e.value.status == 404
    desk.start(t.id, "op")
    assert desk.ticket(t.id)["starting"]
    events = desk.step(1.0, 25, _empty())
    assert [e.type for e in events] == ["ticket_started"]
    assert desk.ticket(t.id)["state"] == "active"
    desk.end(t.id, "op")
    events = desk.step(2.0, 50, _empty())
    assert [e.type for e in events] == ["ticket_completed"]
    done = desk.ticket(t.id)
    assert done["state"] == "completed" and done["result"]["missed"] == [
        "open breaker QF3",
        "earth",
    ]
    with pytest.raises(TicketError, match="ended already"):
        desk.end(t.id)


def _empty() -> People3D:
    z = np.zeros((0, 17))
    return People3D(
        frame=0,
        joints=np.zeros((0, 17, 3)),
        conf=z,
        ids=np.zeros(0, dtype=np.int64),
        reprojection_px=z,
        views=z.astype(np.int64),
        detections=np.zeros((0, 2), dtype=np.int64),
    )
