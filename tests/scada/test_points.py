"""The IEC 60870-5-104 points table: addresses by block, the cameras that see each zone, the CSV
that `stereopose points` prints, and its errors."""

from __future__ import annotations

import csv
import io
import json
from pathlib import Path

import numpy as np
import pytest

from stereopose.calibration.formats import save_calibration
from stereopose.cli import main
from stereopose.fence import Site, Zone, load_site, save_site
from stereopose.scada.points import (
    CAMERA_BASE,
    COMMAND,
    COUNT,
    HEADER,
    RULE_BASE,
    SINGLE,
    TICKET_SLOTS,
    ZONE_BASE,
    cameras_seeing,
    points_table,
)
from stereopose.sim.scene import make_rig

ROOM = (12.0, 8.0, 4.0)
RULES = """
[[rules]]
name = "alone at panel"
type = "lone_worker"
zones = ["panel A"]

[[rules]]
name = "down"
type = "person_down"
"""


@pytest.fixture(scope="module")
def rig():
    return make_rig(4, np.random.default_rng(3), ROOM)


def _square(x: float, y: float, half: float = 0.5) -> list[list[float]]:
    return [[x - half, y - half], [x + half, y - half], [x + half, y + half], [x - half, y + half]]


def _site(folder: Path, *, far: bool = False, names=("panel A", "work, area")) -> Site:
    """A site file in `folder` (zones in the room's middle; far: a third one no camera sees)
    with two rules, read back as serve reads it."""
    zones = [
        Zone(names[0], "energized", np.array(_square(6.0, 4.0)), (0.0, 2.5)),
        Zone(names[1], "work_area", np.array(_square(5.0, 3.0, 1.5)), (0.0, 2.5)),
    ]
    if far:
        zones.append(Zone("far away", "restricted", np.array(_square(900.0, 900.0)), (0.0, 2.0)))
    path = folder / "site.toml"
    save_site(path, Site(tuple(zones), 25.0))
    path.write_text(path.read_text() + RULES.replace('"panel A"', json.dumps(names[0])))
    return load_site(path)


def _config(folder: Path, rig, extra: str = "") -> Path:
    save_calibration(folder / "calib.toml", rig)
    cams = "".join(f'[[cameras]]\nname = "{n}"\nsource = "{n}.mp4"\n\n' for n in rig.names)
    path = folder / "serve.toml"
    path.write_text(f'calibration = "calib.toml"\nsite = "site.toml"\n\n{cams}{extra}')
    return path


def test_addresses_come_in_blocks_and_follow_the_files_order(tmp_path: Path, rig) -> None:
    site = _site(tmp_path)
    table = points_table(site, rig)
    ioas = [p.ioa for p in table]
    assert ioas == sorted(ioas) and len(set(ioas)) == len(ioas)
    assert [table.get("camera_up", n).ioa for n in rig.names] == [
        CAMERA_BASE + k for k in range(1, 5)
    ]
    assert table.get("zone_occupied", "panel A").ioa == ZONE_BASE + 11
    assert table.get("zone_alarm", "panel A").ioa == ZONE_BASE + 12
    assert table.get("zone_occupied", "work, area").ioa == ZONE_BASE + 21
    assert table.get("rule_alarm", "alone at panel").ioa == RULE_BASE + 12
    assert table.get("rule_alarm", "down").ioa == RULE_BASE + 22
    assert table.get("people").type == COUNT and table.get("unacknowledged").type == COUNT
    assert table.get("service_running").type == table.get("service_degraded").type == SINGLE
    assert not any(p.command for p in table)  # commands off by default
    # 2 service + 2 counts + 4 cameras + 2 per zone + 1 per rule + 3 per ticket slot
    assert len(table) == 4 + 4 + 2 * 2 + 2 + 3 * TICKET_SLOTS
    assert table.get("ticket_active", "1").ioa == 40_011
    assert table.get("ticket_steps", str(TICKET_SLOTS)).type == COUNT
    # each point names its zone, rule or camera
    for p in table:
        if p.name is not None:
            assert p.name in p.meaning


def test_commands_add_one_per_zone_and_priority(tmp_path: Path, rig) -> None:
    table = points_table(_site(tmp_path), rig, commands=True)
    commands = [p for p in table if p.command]
    assert {p.kind for p in commands} == {"ack_zone", "ack_priority"}
    assert [p.name for p in commands if p.kind == "ack_priority"] == ["1", "2", "3", "4"]
    assert table.get("ack_zone", "panel A").ioa == ZONE_BASE + 19
    assert all(p.type == COMMAND for p in commands)
    assert len(table.monitored) == len(table) - 6


def test_a_zone_is_seen_by_the_cameras_that_have_it_in_their_image(tmp_path: Path, rig) -> None:
    site = _site(tmp_path, far=True)
    middle, _, far = site.zones
    # every simulated camera looks at the room's middle; nobody sees 900 m away
    assert cameras_seeing(middle, rig) == rig.names
    assert cameras_seeing(far, rig) == ()
    table = points_table(site, rig)
    assert table.get("zone_occupied", "panel A").cameras == rig.names
    unseen = table.get("zone_occupied", "far away")
    assert unseen.unseen and "no camera sees it" in unseen.source
    # the lone worker rule watches panel A: its cameras; person_down the whole site
    assert table.get("rule_alarm", "alone at panel").cameras == rig.names
    assert table.get("rule_alarm", "down").cameras == rig.names


def test_a_zone_behind_a_camera_is_not_seen_by_it(rig) -> None:
    cam = rig[0]
    # a zone 2 m behind the first camera (opposite its optical axis), at its height
    back = cam.center - 2.0 * cam.R[2]
    z = Zone(
        "behind",
        "restricted",
        np.array(_square(back[0], back[1], 0.2)),
        (back[2] - 0.1, back[2] + 0.1),
    )
    assert cam.name not in cameras_seeing(z, rig)


def test_the_csv_reads_back_as_the_table_whatever_the_names(tmp_path: Path, rig) -> None:
    hostile = ('pa"nel, A\nsecond line', "=cmd|' /C calc'!A0")
    table = points_table(_site(tmp_path, names=hostile), rig, commands=True)
    rows = list(csv.reader(io.StringIO(table.csv())))
    assert tuple(rows[0]) == HEADER
    assert rows[1:] == [list(r) for r in table.rows()]
    assert any(hostile[0] in r[2] for r in rows[1:])
    # no cell starts with a name: a spreadsheet never reads one as a formula
    assert not any(cell.startswith(("=", "+", "-", "@")) for r in rows for cell in r)


def test_the_points_command_prints_the_table_of_the_configuration(
    tmp_path: Path, rig, capsys
) -> None:
    site = _site(tmp_path)
    path = _config(tmp_path, rig, "[iec104]\nenabled = true\ncommands = true\n")
    assert main(["points", str(path)]) == 0
    printed = capsys.readouterr()
    assert "Traceback" not in printed.err
    rows = list(csv.reader(io.StringIO(printed.out)))
    assert tuple(rows[0]) == HEADER
    assert rows[1:] == [list(r) for r in points_table(site, rig, commands=True).rows()]


def test_the_points_command_says_when_the_outstation_is_off(tmp_path: Path, rig, capsys) -> None:
    _site(tmp_path)
    assert main(["points", str(_config(tmp_path, rig))]) == 0
    printed = capsys.readouterr()
    assert "[iec104] is not enabled" in printed.err
    assert printed.out.startswith(",".join(HEADER) + "\n")


@pytest.mark.parametrize(
    ("extra", "expected"),
    [
        ("[iec104]\nport = 70000\n", "iec104.port: expected an integer in [1, 65535]"),
        ('[iec104]\nhost = "substation.local"\n', "iec104.host: expected an IPv4 address"),
        ("[iec104]\nallowed_clients = []\n", "iec104.allowed_clients: empty"),
        ('[iec104]\nallowed_clients = ["10.0.0.0/33"]\n', "iec104.allowed_clients[0]"),
        ("[iec104]\ncomon_address = 3\n", "iec104: unknown key(s) comon_address"),
        ('[iec104]\ntime_tags = "gps"\n', "iec104.time_tags: expected one of"),
        ("[iec104\n", "invalid TOML"),
    ],
)
def test_a_bad_configuration_is_exit_2_naming_the_file_and_the_key(
    tmp_path: Path, rig, capsys, extra: str, expected: str
) -> None:
    _site(tmp_path)
    path = _config(tmp_path, rig, extra)
    assert main(["points", str(path)]) == 2
    printed = capsys.readouterr()
    err = " ".join(printed.err.split())
    assert str(path) in err and expected in err, err
    assert "Traceback" not in printed.err and printed.out == ""


def test_a_missing_configuration_or_site_is_exit_2_naming_it(tmp_path: Path, rig, capsys) -> None:
    assert main(["points", str(tmp_path / "nothing.toml")]) == 2
    assert "nothing.toml: configuration file not found" in capsys.readouterr().err
    path = _config(tmp_path, rig)  # its site.toml not written
    assert main(["points", str(path)]) == 2
    err = " ".join(capsys.readouterr().err.split())
    assert "site.toml" in err and "Traceback" not in err
