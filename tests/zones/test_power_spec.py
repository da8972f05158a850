"""A zone's state source and voltage in the site file: each form read, every mistake an error
naming the file, the zone and the key; the approach margin from the voltage's table row."""

from __future__ import annotations

from pathlib import Path

import pytest

from stereopose.cli import main
from stereopose.errors import ConfigError
from stereopose.fence import load_site, save_site
from stereopose.zones.distances import TABLES, approach_distance
from stereopose.zones.power import parse_power

ZONE = """
[[zones]]
name = "bay2_panel"
kind = "{kind}"
polygon = [[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]]
z = [0.0, 2.5]
{more}
"""
RTU = 'host = "10.0.0.5", common_address = 1'


def _site(tmp_path: Path, more: str, kind: str = "energized") -> Path:
    path = tmp_path / "site.toml"
    path.write_text(ZONE.format(kind=kind, more=more))
    return path


@pytest.mark.parametrize(
    ("table", "kv", "metres"),
    [
        ("gb26860", 10, 0.70),
        ("gb26860", 0.4, 0.70),
        ("gb26860", 35, 1.00),
        ("gb26860", 66, 1.50),
        ("gb26860", 110, 1.50),
        ("gb26860", 220, 3.00),
        ("gb26860", 500, 5.00),
        ("gb26860", 15, 1.00),  # between rows: the higher row
        ("en50110", 10, 1.15),
        ("en50110", 380, 4.00),
        ("osha", 13.8, 0.6096),
        ("osha", 138, 1.3716),
    ],
)
def test_a_voltage_gives_its_tables_distance(table: str, kv: float, metres: float) -> None:
    assert approach_distance(kv, table, "zone 'x'") == pytest.approx(metres, abs=1e-4)


def test_the_margin_defaults_from_the_voltage_and_an_explicit_one_wins(tmp_path: Path) -> None:
    assert load_site(_site(tmp_path, "voltage_kv = 110")).zones[0].margin_m == 1.5
    site = load_site(_site(tmp_path, 'voltage_kv = 110\ndistance_table = "en50110"'))
    assert site.zones[0].margin_m == 2.0
    assert load_site(_site(tmp_path, "voltage_kv = 110\nmargin_m = 0.4")).zones[0].margin_m == 0.4
    # the site file written back reads the same
    save_site(tmp_path / "again.toml", site)
    again = load_site(tmp_path / "again.toml").zones[0]
    assert (again.margin_m, again.voltage_kv, again.distance_table) == (2.0, 110.0, "en50110")


@pytest.mark.parametrize(
    ("more", "kind", "wanted"),
    [
        ("voltage_kv = 1200", "energized", "voltage_kv = 1200 is outside gb26860"),
        ('voltage_kv = 200\ndistance_table = "osha"', "energized", "up to 140 kV"),
        ('voltage_kv = 0.1\ndistance_table = "osha"', "energized", "above 0.3 kV"),
        ('voltage_kv = "10 kV"', "energized", "voltage_kv: expected a number"),
        ('voltage_kv = 10\ndistance_table = "nesc"', "energized", "distance_table: expected one"),
        ('distance_table = "osha"', "energized", "needs voltage_kv"),
        ("voltage_kv = 10", "work_area", "only for an energized zone"),
        ('state = { modbus = { host = "x" } }', "energized", "unknown key(s) modbus"),
        ("state = { iec104 = { common_address = 1, ioa = 5 } }", "energized", "missing `host`"),
        (f"state = {{ iec104 = {{ {RTU}, ioa = 5, type = 'triple' }} }}", "energized", "type"),
        (f"state = {{ iec104 = {{ {RTU}, ioa = 99999999 }} }}", "energized", "ioa"),
        ('state = { opcua = { endpoint = "http://x", node_id = "n" } }', "energized", "opc.tcp"),
        ('state = { mqtt = { topic = "a/+/b" } }', "energized", "no wildcard"),
        (
            f'[zones.state]\ndead_when = "qf == 1"\nenergized_when = "qf == 2"\n'
            f"[zones.state.points]\nqf = {{ iec104 = {{ {RTU}, ioa = 1 }} }}",
            "energized",
            "one of dead_when or energized_when",
        ),
        (
            f"[zones.state]\ndead_when = \"__import__('os')\"\n[zones.state.points]\n"
            f"qf = {{ iec104 = {{ {RTU}, ioa = 1 }} }}",
            "energized",
            "Call is not allowed",
        ),
        (
            f'[zones.state]\ndead_when = "qx == 1"\n[zones.state.points]\n'
            f"qf = {{ iec104 = {{ {RTU}, ioa = 1 }} }}",
            "energized",
            "qx not among the points",
        ),
    ],
)
def test_a_bad_state_or_voltage_names_the_zone_and_key(
    tmp_path: Path, more: str, kind: str, wanted: str
) -> None:
    with pytest.raises(ConfigError) as e:
        load_site(_site(tmp_path, more, kind))
    assert "site.toml" in str(e.value) and "bay2_panel" in str(e.value)
    assert wanted in str(e.value)


def test_an_unknown_voltage_is_exit_2_naming_the_zone(
    tmp_path: Path, capsys, shared_data_dir: Path
) -> None:
    site = _site(tmp_path, "voltage_kv = 1500")
    pose = shared_data_dir / "pose"
    rc = main(
        [
            "reconstruct",
            "--calib",
            str(shared_data_dir / "calib.toml"),
            "--pose",
            str(pose),
            "--out",
            str(tmp_path / "o.jsonl"),
            "--site",
            str(site),
        ]
    )
    assert rc == 2
    err = capsys.readouterr().err
    assert "bay2_panel" in err and "1500" in err and "1000 kV" in err


def test_the_rules_read_the_points() -> None:
    spec = parse_power(
        {
            "dead_when": "qf == 'open' and (qe == 'closed' or not volts > 0.5)",
            "points": {
                "qf": {"iec104": {"host": "h", "common_address": 1, "ioa": 1, "type": "double"}},
                "qe": {"mqtt": {"topic": "qe"}},
                "volts": {"opcua": {"endpoint": "opc.tcp://h:4840", "node_id": "ns=2;s=V"}},
            },
        },
        "zone 'z'",
    )
    assert spec.is_dead({"qf": "open", "qe": "CLOSED", "volts": 10.0})
    assert spec.is_dead({"qf": "open", "qe": "open", "volts": 0.0})
    assert not spec.is_dead({"qf": "closed", "qe": "closed", "volts": 0.0})
    with pytest.raises(ValueError, match="cannot order"):  # the zone unknown, never dead
        spec.is_dead({"qf": "open", "qe": "open", "volts": "n/a"})
    one = parse_power({"iec104": {"host": "h", "common_address": 1, "ioa": 1}}, "zone 'z'")
    assert one.is_dead({"state": "off"}) and not one.is_dead({"state": "on"})
    assert one.stale_after(one.points[0]) == 90.0  # 1.5 interrogation periods
    assert set(TABLES) == {"gb26860", "en50110", "osha"}


def test_an_endpoints_login_is_never_in_a_source_label() -> None:
    spec = parse_power(
        {"opcua": {"endpoint": "opc.tcp://scada:hunter2@10.0.0.6:4840", "node_id": "ns=2;s=QF"}},
        "zone 'z'",
    )
    assert "hunter2" not in spec.points[0].label and "10.0.0.6:4840" in spec.points[0].label
