"""The site file's [[rules]]: read, written back, and every bad definition a clear error naming
the file and the rule."""

from __future__ import annotations

from pathlib import Path

import pytest

from stereopose.behaviour import (
    ImmobileRule,
    LoneWorkerRule,
    OverreachRule,
    PersonDownRule,
    WorkPositionRule,
    parse_rules,
)
from stereopose.cli import main
from stereopose.errors import ConfigError
from stereopose.fence import load_site, save_site
from stereopose.skeleton import JOINT_INDEX

ZONES = """
fps = 25.0
[[zones]]
name = "panel_A"
kind = "energized"
polygon = [[0.0, 2.0], [0.6, 2.0], [0.6, 4.0], [0.0, 4.0]]
z = [0.0, 2.5]
[[zones]]
name = "front_A"
kind = "work_area"
polygon = [[0.6, 2.0], [1.6, 2.0], [1.6, 4.0], [0.6, 4.0]]
z = [0.0, 2.5]
"""

RULES = """
[[rules]]
name = "man_down"
type = "person_down"
down_s = 3

[[rules]]
name = "two_man"
type = "lone_worker"
zones = ["panel_A"]
buddy_m = 2.5
lone_s = 10.0

[[rules]]
name = "position_A"
type = "work_position"
zone = "front_A"
facing_deg = 180.0
tolerance_deg = 25.0
postures = ["standing", "crouching"]

[[rules]]
name = "still"
type = "immobile"
immobile_s = 30.0

[[rules]]
name = "overhead"
type = "overreach"
max_height_m = 2.1
joints = ["left_wrist", "right_wrist", "left_elbow"]
"""


def write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "site.toml"
    path.write_text(text, encoding="utf-8")
    return path


def test_rules_are_read_with_their_parameters_and_defaults(tmp_path: Path) -> None:
    site = load_site(write(tmp_path, ZONES + RULES))
    down, lone, pos, still, over = site.rules
    assert down == PersonDownRule("man_down", down_s=3.0)
    assert down.up_s == 1.0 and down.fall_speed_m_s == 1.0  # the defaults
    assert lone == LoneWorkerRule("two_man", ("panel_A",), buddy_m=2.5, lone_s=10.0)
    assert pos == WorkPositionRule(
        "position_A", "front_A", 180.0, tolerance_deg=25.0, postures=("standing", "crouching")
    )
    assert still == ImmobileRule("still", 30.0)
    assert over == OverreachRule(
        "overhead",
        2.1,
        joints=tuple(sorted(JOINT_INDEX[j] for j in ("left_wrist", "right_wrist", "left_elbow"))),
    )
    assert [r.type for r in site.rules] == [
        "person_down",
        "lone_worker",
        "work_position",
        "immobile",
        "overreach",
    ]


def test_a_site_without_rules_has_none(tmp_path: Path) -> None:
    assert load_site(write(tmp_path, ZONES)).rules == ()


def test_rules_written_back_read_the_same(tmp_path: Path) -> None:
    site = load_site(write(tmp_path, ZONES + RULES))
    out = tmp_path / "again.toml"
    save_site(out, site)
    again = load_site(out)
    assert again.rules == site.rules and [z.name for z in again.zones] == ["panel_A", "front_A"]
    assert "buddy_m = 2.5" in out.read_text() and "down_s" not in out.read_text()  # default


def _rule(**kw) -> str:
    lines = ["[[rules]]"]
    for k, v in kw.items():
        lines.append(f"{k} = {v}")
    return "\n".join(lines) + "\n"


@pytest.mark.parametrize(
    ("rule", "message"),
    [
        (_rule(name='"x"', type='"falling"'), "rule 'x': unknown type 'falling'; expected one of"),
        (_rule(name='"x"'), "rule 'x': missing `type`"),
        (_rule(type='"immobile"', immobile_s=3), "rules[0]: missing `name`"),
        (_rule(name="3", type='"immobile"'), "rules[0]: name must be a non-empty string"),
        (
            _rule(name='"x"', type='"person_down"', downs=3),
            "rule 'x': unknown key(s) downs; person_down knows name, type, down_s",
        ),
        (_rule(name='"x"', type='"immobile"'), "rule 'x': missing `immobile_s`"),
        (
            _rule(name='"x"', type='"person_down"', down_s=-1),
            "rule 'x': down_s: expected a finite number in (0, 86400], got -1",
        ),
        (_rule(name='"x"', type='"person_down"', down_s="nan"), "rule 'x': down_s: expected"),
        (_rule(name='"x"', type='"person_down"', down_s='"3"'), "rule 'x': down_s: expected"),
        (_rule(name='"x"', type='"person_down"', down_s="true"), "rule 'x': down_s: expected"),
        (
            _rule(name='"x"', type='"lone_worker"', zones='["panel_B"]'),
            "rule 'x': zones: no zone named 'panel_B'; zones: front_A, panel_A",
        ),
        (
            _rule(name='"x"', type='"lone_worker"', zones="[]"),
            "rule 'x': zones must be a non-empty list of names",
        ),
        (_rule(name='"x"', type='"lone_worker"'), "rule 'x': missing `zones`"),
        (
            _rule(name='"x"', type='"lone_worker"', zones='["panel_A"]', buddy_m=0),
            "rule 'x': buddy_m: expected a finite number in (0, 10000], got 0",
        ),
        (
            _rule(name='"x"', type='"work_position"', zone='"panel_A"', facing_deg=0),
            "rule 'x': zone: zone 'panel_A' is energized; expected a work_area zone",
        ),
        (
            _rule(name='"x"', type='"work_position"', zone='"front_A"'),
            "rule 'x': missing `facing_deg`",
        ),
        (
            _rule(
                name='"x"',
                type='"work_position"',
                zone='"front_A"',
                facing_deg=0,
                tolerance_deg=200,
            ),
            "rule 'x': tolerance_deg: expected a finite number in (0, 180]",
        ),
        (
            _rule(
                name='"x"',
                type='"work_position"',
                zone='"front_A"',
                facing_deg=0,
                postures='["sitting"]',
            ),
            "rule 'x': postures: unknown posture(s) 'sitting'",
        ),
        (
            _rule(
                name='"x"',
                type='"work_position"',
                zone='"front_A"',
                facing_deg=0,
                energized='["front_A"]',
            ),
            "rule 'x': energized: zone 'front_A' is work_area",
        ),
        (
            _rule(name='"x"', type='"overreach"', max_height_m=2, joints='["left_hand"]'),
            "rule 'x': joints: unknown joint 'left_hand'",
        ),
        (_rule(name='"x"', type='"immobile"', immobile_s=1e400), "rule 'x': immobile_s: expected"),
        (
            _rule(name='"x"', type='"person_down"', priority=0),
            "rule 'x': priority: expected an integer in [1, 4] or one of critical, high, "
            "medium, low",
        ),
        (_rule(name='"x"', type='"person_down"', priority='"top"'), "rule 'x': priority: expected"),
        (
            _rule(name='"x"', type='"immobile"', immobile_s=5, rearm_s=-1),
            "rule 'x': rearm_s: expected a finite number in [0, 86400], got -1",
        ),
        (
            _rule(name='"x"', type='"immobile"', immobile_s=5, rearm_s=1e6),
            "rule 'x': rearm_s: expected",
        ),
        (
            _rule(name='"x"', type='"immobile"', immobile_s=5)
            + _rule(name='"x"', type='"immobile"', immobile_s=6),
            "rule 'x': the name is used twice",
        ),
    ],
)
def test_bad_rule_definitions_name_the_file_and_the_rule(
    tmp_path: Path, rule: str, message: str
) -> None:
    path = write(tmp_path, ZONES + rule)
    with pytest.raises(ConfigError) as err:
        load_site(path)
    text = str(err.value)
    assert text.startswith(f"{path}: ") and message in text, text


def test_rules_must_be_tables_and_not_too_many(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"site.toml: rules must be \[\[rules\]\] tables"):
        load_site(write(tmp_path, 'rules = "all"\n' + ZONES))
    with pytest.raises(ConfigError, match=r"rules\[0\]: expected a table"):
        load_site(write(tmp_path, "rules = [1]\n" + ZONES))
    many = [{"name": f"r{k}", "type": "person_down"} for k in range(101)]
    with pytest.raises(ConfigError, match="101 rules; a site holds at most 100"):
        parse_rules(many, "here", ())


def test_work_position_needs_an_energized_zone_somewhere(tmp_path: Path) -> None:
    site = ZONES.replace('kind = "energized"', 'kind = "restricted"')
    rule = _rule(name='"x"', type='"work_position"', zone='"front_A"', facing_deg=0)
    with pytest.raises(ConfigError, match="rule 'x': the site has no energized zone"):
        load_site(write(tmp_path, site + rule))


def test_a_bad_rule_is_exit_2_on_the_command_line(tmp_path: Path, capsys) -> None:
    scene = tmp_path / "scene"
    assert main(["simulate", str(scene), "--frames", "3", "--cameras", "2", "--people", "1"]) == 0
    capsys.readouterr()
    site = write(tmp_path, ZONES + _rule(name='"down"', type='"person_down"', down_s=0))
    rc = main(
        [
            "reconstruct",
            "--calib",
            str(scene / "calib.toml"),
            "--pose",
            str(scene / "pose"),
            "--out",
            str(tmp_path / "p.jsonl"),
            "--site",
            str(site),
        ]
    )
    err = capsys.readouterr().err
    assert rc == 2
    assert "site.toml: rule 'down': down_s: expected" in " ".join(err.split())
    assert "Traceback" not in err


def test_postures_thresholds_from_the_site(tmp_path: Path) -> None:
    site = load_site(write(tmp_path, ZONES + "[postures]\nbend_deg = 35\nmin_samples = 50\n"))
    assert site.postures.bend_deg == 35.0 and site.postures.min_samples == 50
    assert site.postures.lying_height_m == 0.7  # the rest keep their defaults
    assert load_site(write(tmp_path, ZONES)).postures is None
    out = tmp_path / "again.toml"
    save_site(out, site)
    assert load_site(out).postures == site.postures


@pytest.mark.parametrize(
    ("table", "message"),
    [
        ("bend = 35", "[postures]: unknown key(s) bend; known: standing_hip_m"),
        ("bend_deg = 0", "[postures] bend_deg: expected a finite number in (0, 180], got 0"),
        ("min_joints = 2.5", "[postures] min_joints: expected an integer in [1, 17]"),
        ("low_hip_ratio = 1", "[postures] low_hip_ratio: expected a finite number in (0, 1)"),
        ('reach_m = "far"', "[postures] reach_m: expected"),
    ],
)
def test_bad_posture_thresholds_name_the_file_and_key(
    tmp_path: Path, table: str, message: str
) -> None:
    path = write(tmp_path, ZONES + "[postures]\n" + table + "\n")
    with pytest.raises(ConfigError) as err:
        load_site(path)
    assert str(err.value).startswith(f"{path}: ") and message in str(err.value), str(err.value)


def test_the_run_applies_the_sites_rules_and_thresholds(tmp_path: Path) -> None:
    from stereopose.config import Config
    from stereopose.pipeline.loop import behaviour_monitor

    assert behaviour_monitor(None, Config()) is None
    assert behaviour_monitor(load_site(write(tmp_path, ZONES)), Config()) is None
    only = behaviour_monitor(
        load_site(write(tmp_path, ZONES + "[postures]\nbend_deg = 35\n")), Config()
    )
    assert only is not None and only.rules == () and only.tracker.settings.bend_deg == 35.0
    both = behaviour_monitor(load_site(write(tmp_path, ZONES + RULES)), Config())
    assert [r.name for r in both.rules] == [
        "man_down",
        "two_man",
        "position_A",
        "still",
        "overhead",
    ]
    assert both.lost_s == Config().tracking.max_lost_s


def test_every_rule_type_takes_a_priority_and_a_rearm_time(tmp_path: Path) -> None:
    from stereopose.alarms.priority import DEFAULT_REARM_S

    text = ZONES + RULES.replace("down_s = 3\n", 'down_s = 3\npriority = "medium"\nrearm_s = 5\n')
    text = text.replace("immobile_s = 30.0\n", "immobile_s = 30.0\npriority = 1\n")
    site = load_site(write(tmp_path, text))
    down, lone, _, still, _ = site.rules
    assert (down.priority, down.rearm_s) == (3, 5.0)
    assert (still.priority, still.rearm_s) == (1, DEFAULT_REARM_S)
    assert (lone.priority, lone.rearm_s) == (None, DEFAULT_REARM_S)
    out = tmp_path / "again.toml"
    save_site(out, site)
    assert load_site(out).rules == site.rules
    written = out.read_text()
    assert written.count("priority") == 2 and written.count("rearm_s") == 1
    assert PersonDownRule("d", priority="low").priority == 4
    with pytest.raises(ConfigError, match="rule 'd': priority: expected"):
        PersonDownRule("d", priority=0)
