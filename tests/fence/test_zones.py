"""Zone geometry and the site file."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from stereopose.errors import ConfigError
from stereopose.fence.site import load_site
from stereopose.zones import Zone, ZoneGeometry

SQUARE = [[0.0, 0.0], [2.0, 0.0], [2.0, 2.0], [0.0, 2.0]]
PANEL = "[[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]]"
# a U open to +y: the notch 1 < x < 2, y > 1 is outside
U_SHAPE = [[0, 0], [3, 0], [3, 3], [2, 3], [2, 1], [1, 1], [1, 3], [0, 3]]


def geometry(*polys, z=(0.0, 2.0)) -> ZoneGeometry:
    return ZoneGeometry(
        tuple(Zone(f"z{k}", "energized", np.array(p, float), z) for k, p in enumerate(polys))
    )


def test_inside_square_edges_and_height_band() -> None:
    g = geometry(SQUARE)
    pts = np.array(
        [
            [1.0, 1.0, 1.0],  # inside
            [0.0, 1.0, 1.0],  # on an edge
            [2.0, 2.0, 0.0],  # on a corner, on the floor
            [1.0, 1.0, 2.0],  # at the top of the band
            [1.0, 1.0, 2.01],  # above
            [2.01, 1.0, 1.0],  # just outside
            [np.nan, 1.0, 1.0],
        ]
    )
    np.testing.assert_array_equal(g.inside(pts)[:, 0], [1, 1, 1, 1, 0, 0, 0])


def test_concave_polygon() -> None:
    g = geometry(U_SHAPE, U_SHAPE[::-1])  # either orientation
    pts = np.array([[0.5, 2.5, 1], [1.5, 2.5, 1], [2.5, 2.5, 1], [1.5, 0.5, 1], [1.5, 1.0, 1]])
    expect = [1, 0, 1, 1, 1]  # the notch is outside, its floor edge inside
    np.testing.assert_array_equal(g.inside(pts), np.array([expect, expect]).T)


def test_distances_to_the_prism() -> None:
    g = geometry(SQUARE)
    pts = np.array(
        [
            [1.0, 1.0, 1.0],  # inside: 0
            [3.0, 1.0, 1.0],  # 1 m beside
            [1.0, 1.0, 2.5],  # 0.5 m above
            [3.0, 3.0, 1.0],  # diagonal to a corner: sqrt(2)
            [3.0, 1.0, 3.0],  # beside and above: sqrt(1 + 1)
            [1.5, 1.0, 1.0],  # inside, 0.5 m from an edge: still 0
        ]
    )
    inside, dist = g.distance(pts)
    np.testing.assert_allclose(dist[:, 0], [0, 1, 0.5, np.sqrt(2), np.sqrt(2), 0], atol=1e-12)
    np.testing.assert_array_equal(inside[:, 0], [1, 0, 0, 0, 0, 1])


def test_many_zones_at_once_match_one_at_a_time() -> None:
    rng = np.random.default_rng(0)
    polys = [np.array(SQUARE) * rng.uniform(0.5, 2) + rng.uniform(-3, 3, 2) for _ in range(20)]
    pts = rng.uniform(-4, 6, (300, 3))
    together = geometry(*polys).distance(pts)
    for k, p in enumerate(polys):
        alone = geometry(p).distance(pts)
        np.testing.assert_array_equal(together[0][:, k], alone[0][:, 0])
        np.testing.assert_allclose(together[1][:, k], alone[1][:, 0])


ZONE = """
[[zones]]
name = "panel"
kind = "energized"
polygon = [[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]]
z = [0.0, 2.5]
"""


def write(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "site.toml"
    p.write_text(text)
    return p


def test_site_loads_with_defaults_and_options(tmp_path: Path) -> None:
    text = (
        "fps = 30\n"
        + ZONE
        + 'joints = ["left_wrist", "right_wrist"]\nmargin_m = 0.5\ndwell_s = 5\nallowed = [2]\n'
        + ZONE.replace('"panel"', '"bench"').replace("energized", "work_area")
        + "expected = [1]\n"
    )
    site = load_site(write(tmp_path, text))
    assert site.fps == 30.0 and [z.name for z in site.zones] == ["panel", "bench"]
    panel, bench = site.zones
    assert panel.joints == (9, 10) and panel.margin_m == 0.5 and panel.dwell_s == 5.0
    assert panel.allowed == {2} and bench.expected == {1} and len(bench.joints) == 17
    assert bench.enter_s == 0.08 and bench.exit_s == 0.2


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (
            (
                "[[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]]",
                "[[0, 0], [1, 1], [1, 0], [0, 1]]",
            ),
            r"zone 'panel': polygon intersects itself",
        ),
        (
            (PANEL, "[[0, 0], [1, 1], [2, 2]]"),
            r"zone 'panel': polygon is degenerate",
        ),
        ((PANEL, "[[0, 0], [1, 0]]"), "at least 3"),
        (("z = [0.0, 2.5]", "z = [2.5, 0.0]"), r"zone 'panel': height band .* bottom < top"),
        (('kind = "energized"', 'kind = "hot"'), r"zone 'panel': unknown kind 'hot'"),
        (('kind = "energized"', 'kind = "energized"\ncolour = 1'), r"unknown key\(s\) colour"),
        (("z = [0.0, 2.5]", 'z = [0.0, 2.5]\njoints = ["elbow"]'), r"unknown joint 'elbow'"),
        (("z = [0.0, 2.5]", "z = [0.0, 2.5]\nexpected = [1]"), r"only make sense for a work_area"),
        (
            ("z = [0.0, 2.5]", "z = [0.0, 2.5]\nmargin_m = -1"),
            r"margin_m: expected .* \[0, 10000\], got -1",
        ),
        (('name = "panel"\n', ""), r"zones\[0\]: missing `name`"),
        (("z = [0.0, 2.5]", ""), r"zone 'panel': missing `z`"),
    ],
)
def test_bad_zones_are_clear_errors(tmp_path: Path, change, message: str) -> None:
    path = write(tmp_path, ZONE.replace(*change))
    with pytest.raises(ConfigError, match=message) as e:
        load_site(path)
    assert str(path) in str(e.value)


def test_bad_site_files(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="site file not found"):
        load_site(tmp_path / "none.toml")
    with pytest.raises(ConfigError, match="invalid TOML"):
        load_site(write(tmp_path, "[[zones]\n"))
    with pytest.raises(ConfigError, match=r"no \[\[zones\]\]"):
        load_site(write(tmp_path, "fps = 25\n"))
    with pytest.raises(ConfigError, match="used twice"):
        load_site(write(tmp_path, ZONE + ZONE))


def test_site_round_trip(tmp_path: Path) -> None:
    from stereopose.fence import save_site

    text = ZONE + 'joints = ["nose"]\nmargin_m = 0.25\nallowed = [4, 2]\n'
    site = load_site(write(tmp_path, "fps = 12.5\n" + text))
    save_site(tmp_path / "again.toml", site)
    back = load_site(tmp_path / "again.toml")
    assert back.fps == 12.5
    (a,), (b,) = site.zones, back.zones
    assert (a.name, a.kind, a.z, a.joints, a.margin_m, a.allowed) == (
        b.name,
        b.kind,
        b.z,
        b.joints,
        b.margin_m,
        b.allowed,
    )
    np.testing.assert_array_equal(a.polygon, b.polygon)


def test_priority_and_rearm_per_zone(tmp_path: Path) -> None:
    from stereopose.alarms.priority import DEFAULT_REARM_S, HIGH, LOW
    from stereopose.fence import save_site

    text = (
        ZONE
        + 'priority = "high"\nrearm_s = 12.5\n'
        + ZONE.replace('"panel"', '"bench"').replace("energized", "work_area")
        + "priority = 4\n"
        + ZONE.replace('"panel"', '"door"').replace("energized", "restricted")
    )
    site = load_site(write(tmp_path, text))
    panel, bench, door = site.zones
    assert (panel.priority, panel.rearm_s) == (HIGH, 12.5)
    assert (bench.priority, bench.rearm_s) == (LOW, DEFAULT_REARM_S)
    assert (door.priority, door.rearm_s) == (None, DEFAULT_REARM_S)  # the defaults by event
    save_site(tmp_path / "again.toml", site)
    written = (tmp_path / "again.toml").read_text()
    assert written.count("priority") == 2 and written.count("rearm_s") == 1
    back = load_site(tmp_path / "again.toml").zones
    assert [(z.priority, z.rearm_s) for z in back] == [(z.priority, z.rearm_s) for z in site.zones]
    assert Zone("x", "energized", np.array(SQUARE), (0.0, 1.0), priority="critical").priority == 1
    with pytest.raises(ConfigError, match="zone 'x': priority: expected"):
        Zone("x", "energized", np.array(SQUARE), (0.0, 1.0), priority=9)
    with pytest.raises(ConfigError, match="zone 'x': rearm_s: expected"):
        Zone("x", "energized", np.array(SQUARE), (0.0, 1.0), rearm_s=-0.5)


def test_a_bad_priority_is_exit_2_naming_file_zone_and_value(tmp_path: Path, capsys) -> None:
    from stereopose.cli import main

    scene = tmp_path / "scene"
    assert main(["simulate", str(scene), "--frames", "3", "--cameras", "2", "--people", "1"]) == 0
    capsys.readouterr()
    site = write(tmp_path, ZONE + "priority = 7\n")
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
    err = " ".join(capsys.readouterr().err.split())
    assert rc == 2
    assert "site.toml: zone 'panel': priority: expected an integer in [1, 4]" in err
    assert "got 7" in err and "Traceback" not in err
