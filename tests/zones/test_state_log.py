"""A recorded job judged with the states its site had: `reconstruct --zone-states FILE` on the
real demo's detections, the busbar dead by the switching log and then live again; and every bad
switching log an error naming its file and line."""

from __future__ import annotations

import json
from importlib import resources
from pathlib import Path

import pytest

from stereopose.cli import main
from stereopose.errors import ConfigError
from stereopose.fence import load_site
from stereopose.zones.state_log import read_state_log

SITE = resources.files("stereopose") / "data" / "demo_site.toml"


def _site(folder: Path, state: str = "") -> Path:
    path = folder / "site.toml"
    path.write_text(SITE.read_text() + state)
    return path


def _reconstruct(shared: Path, tmp: Path, site: Path, *more: str) -> list[dict]:
    events = tmp / f"events{len(list(tmp.glob('events*')))}.jsonl"
    argv = ["reconstruct", "--calib", str(shared / "calib.toml"), "--pose", str(shared / "pose")]
    argv += ["--out", str(tmp / "poses.jsonl"), "--fps", "60", "--site", str(site)]
    assert main([*argv, "--events", str(events), "--overwrite", *more]) == 0
    return [json.loads(line) for line in events.read_text().splitlines()]


@pytest.mark.realdata
def test_a_dead_busbar_is_information_until_the_log_turns_it_live(shared_data_dir, tmp_path):
    site = _site(tmp_path)
    live = _reconstruct(shared_data_dir, tmp_path, site)
    entries = [e for e in live if e["zone"] == "overhead_busbar" and e["type"] == "enter"]
    assert entries and all(e["kind"] == "energized" and e["incident"] for e in entries)
    first = entries[0]["t"]
    log = tmp_path / "switching.csv"
    log.write_text(
        f"time,zone,state\n0,overhead_busbar,dead\n{first + 0.1:.3f},overhead_busbar,live\n"
    )
    judged = _reconstruct(shared_data_dir, tmp_path, site, "--zone-states", str(log))
    states = [e for e in judged if e["type"] in ("zone_dead", "zone_live")]
    assert [(e["type"], e["source"]) for e in states] == [
        ("zone_dead", "switching.csv:2"),
        ("zone_live", "switching.csv:3"),
    ]
    dead_entry = next(e for e in judged if e["type"] == "enter" and e["t"] == first)
    assert dead_entry["kind"] == "dead" and dead_entry["incident"] is None
    assert dead_entry["source"] == "switching.csv:2"
    # the walker still inside when it turns live: an alarm at once, at the log's time
    at_live = [e for e in judged if e["type"] == "enter" and e["t"] == states[1]["t"]]
    assert at_live and at_live[0]["kind"] == "energized" and at_live[0]["incident"]


def test_a_point_of_the_zones_state_is_judged_by_its_rule(tmp_path):
    state = """
[zones.state]
dead_when = "qf == 'open' and qe == 'closed'"
[zones.state.points]
qf = { mqtt = { topic = "bay/qf" } }
qe = { mqtt = { topic = "bay/qe" } }
"""
    text = SITE.read_text()
    head, _, tail = text.partition('name = "overhead_busbar"')
    site_file = tmp_path / "site.toml"
    # the busbar's table, its state's points added at its end (before the next table)
    end = tail.find("\n[[")
    site_file.write_text(head + 'name = "overhead_busbar"' + tail[:end] + state + tail[end:])
    site = load_site(site_file)
    log = tmp_path / "log.csv"
    log.write_text(
        "time,zone,state\n# the switching\n2,overhead_busbar.qe,closed\n1,overhead_busbar.qf,open\n"
    )
    rows = read_state_log(log, site.zones)
    assert [(r.t, r.point, r.value, r.line) for r in rows] == [
        (1.0, "qf", "open", 3),
        (2.0, "qe", "closed", 2),
    ]
    from stereopose.zones.state_log import StateLogFile

    rule = StateLogFile.read(log, site.zones).rule(site.zones)

    class Ctx:
        def __init__(self, t: float) -> None:
            self.t, self.frame = t, int(t * 10)

    assert [e.type for e in rule.step(Ctx(1.5))] == ["zone_unknown"]  # qe not known yet
    assert [e.type for e in rule.step(Ctx(2.5))] == ["zone_dead"]
    assert set(rule.safe_now()) == {"overhead_busbar"}


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("", "the first line must be `time,zone,state`"),
        ("t,z,s\n", "the first line must be `time,zone,state`"),
        ("time,zone,state\n", "the switching log has no rows"),
        ("time,zone,state\nsoon,overhead_busbar,dead\n", "log.csv:2: time 'soon'"),
        ("time,zone,state\n-1,overhead_busbar,dead\n", "log.csv:2: time '-1'"),
        ("time,zone,state\nnan,overhead_busbar,dead\n", "log.csv:2: time 'nan'"),
        ("time,zone,state\n1,nowhere,dead\n", "log.csv:2: 'nowhere' is not an energized zone"),
        ("time,zone,state\n1,work_area,dead\n", "log.csv:2: 'work_area' is not an energized"),
        ("time,zone,state\n1,overhead_busbar,off\n", "log.csv:2: state 'off'"),
        ("time,zone,state\n1,overhead_busbar.qf,open\n", "has no state point 'qf'"),
        ("time,zone,state\n1,overhead_busbar\n", "log.csv:2: expected time,zone,state"),
    ],
)
def test_a_bad_switching_log_names_its_file_and_line(tmp_path, text, message):
    site = load_site(_site(tmp_path))
    log = tmp_path / "log.csv"
    log.write_text(text)
    with pytest.raises(ConfigError, match=message.replace("(", r"\(")):
        read_state_log(log, site.zones)


def test_a_missing_or_binary_log_is_a_clear_error(tmp_path):
    site = load_site(_site(tmp_path))
    with pytest.raises(ConfigError, match=r"nothing\.csv: cannot read the switching log"):
        read_state_log(tmp_path / "nothing.csv", site.zones)
    (tmp_path / "bin.csv").write_bytes(b"\xff\xfe\x00")
    with pytest.raises(ConfigError, match=r"bin\.csv: the switching log is not UTF-8"):
        read_state_log(tmp_path / "bin.csv", site.zones)


@pytest.mark.realdata
def test_reconstruct_refuses_zone_states_without_a_site(shared_data_dir, tmp_path, capsys):
    log = tmp_path / "log.csv"
    log.write_text("time,zone,state\n0,a,dead\n")
    argv = ["reconstruct", "--calib", str(shared_data_dir / "calib.toml")]
    argv += ["--pose", str(shared_data_dir / "pose"), "--out", str(tmp_path / "x.jsonl")]
    assert main([*argv, "--zone-states", str(log)]) != 0
    assert "--zone-states need a site file" in capsys.readouterr().err


def test_the_ticket_report_says_which_states_the_job_was_judged_with():
    from stereopose.tickets import load_ticket
    from stereopose.viz.report_ticket import ticket_report, view_from_events

    path = resources.files("stereopose") / "data" / "demo_ticket.toml"
    ticket = load_ticket(Path(str(path))).to_dict()
    zone_dead = {"t": 0.0, "type": "zone_dead", "zone": "overhead_busbar"}
    html = ticket_report(view_from_events(ticket, [{**zone_dead, "source": "log.csv:2"}]), ())
    assert "overhead_busbar dead at 0.0 s (log.csv:2)" in html
    assert "every energized zone taken as live" in ticket_report(view_from_events(ticket, []), ())
