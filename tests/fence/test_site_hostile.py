"""Site files: every number in range, zones bounded in size, the self-intersection test exact
and fast; whatever the file holds, loading it gives a checked Site or a ConfigError."""

from __future__ import annotations

import copy
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hostile import numbers, toml_text, values
from stereopose.checks import FPS_MAX, FPS_MIN, MAX_ZONE_VERTICES, SITE_LIMIT_M
from stereopose.errors import ConfigError
from stereopose.fence.site import Site, load_site, save_site
from stereopose.zones import Zone
from stereopose.zones.polygons import self_intersection

FUZZ = settings(
    max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
ZONE: dict[str, Any] = {
    "name": "panel",
    "kind": "energized",
    "polygon": [[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]],
    "z": [0.0, 2.5],
}


def site_file(tmp_path: Path, zone: dict[str, Any] | None = None, **top: Any) -> Path:
    path = tmp_path / "site.toml"
    path.write_text(toml_text({**top, "zones": [zone or ZONE]}), encoding="utf-8")
    return path


def star(n: int, seed: int = 0) -> np.ndarray:
    """A simple polygon of n vertices (a star-shaped ring with random radii)."""
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    r = 1 + 0.4 * np.random.default_rng(seed).random(n)
    return np.c_[r * np.cos(t), r * np.sin(t)]


@pytest.mark.parametrize(
    ("top", "zone", "message"),
    [
        ({"fps": 1e-300}, {}, r"fps: expected a finite number in \[0.1, 1000\], got 1e-300"),
        ({"fps": math.nan}, {}, r"fps: expected .*got nan"),
        ({"fps": 0}, {}, r"fps: expected .*got 0"),
        ({"fps": 1001}, {}, r"fps: expected .*got 1001"),
        ({"fps": True}, {}, r"fps: expected .*got True"),
        ({}, {"polygon": [[0, 0], [1e300, 0], [1, 1]]}, r"polygon\[1\]\[0\]: .*got 1e\+300"),
        ({}, {"polygon": [[0, 0], [1, math.nan], [1, 1]]}, r"polygon\[1\]\[1\]: .*got nan"),
        ({}, {"polygon": [[0, 0], [1, 0], [True, 1]]}, r"polygon must be a list of \[x, y\]"),
        ({}, {"polygon": [[0, 0], [1, 0], ["1", 1]]}, r"polygon must be a list of \[x, y\]"),
        ({}, {"polygon": [[0, 0], [1, 0], [10**400, 1]]}, r"polygon must be a list"),
        ({}, {"z": [0.0, math.inf]}, r"zone 'panel': z: expected .*got inf"),
        ({}, {"z": [-1e5, 1.0]}, r"zone 'panel': z: expected .*got -100000.0"),
        ({}, {"z": [1.0, 1.0]}, r"bottom < top"),
        ({}, {"dwell_s": 0}, r"zone 'panel': dwell_s: expected .* \(0, 86400\], got 0.0"),
        ({}, {"enter_s": math.nan}, r"zone 'panel': enter_s: expected .*got nan"),
        ({}, {"exit_s": 1e9}, r"zone 'panel': exit_s: expected .*got 1000000000.0"),
        ({}, {"allowed": [-1]}, r"zone 'panel': allowed: expected a list of person ids"),
        ({}, {"allowed": [2**70]}, r"zone 'panel': allowed: expected a list of person ids"),
        ({}, {"kind": 3}, r"zone 'panel': kind must be one of"),
        ({}, {"priority": 0}, r"zone 'panel': priority: expected an integer in \[1, 4\] or one"),
        ({}, {"priority": 5}, r"zone 'panel': priority: .*got 5"),
        ({}, {"priority": 1.5}, r"zone 'panel': priority: .*got 1.5"),
        ({}, {"priority": True}, r"zone 'panel': priority: .*got True"),
        ({}, {"priority": "urgent"}, r"zone 'panel': priority: .*critical, high, medium, low"),
        ({}, {"rearm_s": -1}, r"zone 'panel': rearm_s: expected .* \[0, 86400\], got -1.0"),
        ({}, {"rearm_s": math.inf}, r"zone 'panel': rearm_s: expected .*got inf"),
        ({}, {"rearm_s": "30"}, r"zone 'panel': rearm_s: expected a number, got '30'"),
        ({}, {"name": 3}, r"zones\[0\]: name must be a non-empty string, got 3"),
    ],
)
def test_bad_numbers_name_file_zone_key_and_value(tmp_path, top, zone, message) -> None:
    path = site_file(tmp_path, ZONE | zone, **top)
    with pytest.raises(ConfigError, match=message) as e:
        load_site(path)
    assert str(e.value).startswith(f"{path}: ")


def test_the_bounds_themselves_load(tmp_path: Path) -> None:
    for fps in (FPS_MIN, FPS_MAX):
        assert load_site(site_file(tmp_path, fps=fps)).fps == fps
    edge = [[-SITE_LIMIT_M, -SITE_LIMIT_M], [SITE_LIMIT_M, -SITE_LIMIT_M], [0.0, SITE_LIMIT_M]]
    zone = ZONE | {"polygon": edge, "z": [-SITE_LIMIT_M, SITE_LIMIT_M]}
    assert load_site(site_file(tmp_path, zone)).zones[0].z == (-SITE_LIMIT_M, SITE_LIMIT_M)


def test_zones_have_at_most_1000_vertices(tmp_path: Path) -> None:
    ok = ZONE | {"polygon": star(MAX_ZONE_VERTICES).tolist()}
    assert load_site(site_file(tmp_path, ok)).zones[0].polygon.shape == (MAX_ZONE_VERTICES, 2)
    big = ZONE | {"polygon": star(4500).tolist()}
    with pytest.raises(ConfigError, match=r"zone 'panel': polygon has 4500 points; at most 1000"):
        load_site(site_file(tmp_path, big))


def test_a_site_holds_at_most_1000_zones(tmp_path: Path) -> None:
    path = tmp_path / "site.toml"
    zones = [ZONE | {"name": f"z{k}"} for k in range(1001)]
    path.write_text(toml_text({"zones": zones}))
    with pytest.raises(ConfigError, match="1001 zones; a site holds at most 1000"):
        load_site(path)


def test_a_self_intersection_of_a_large_zone_is_found() -> None:
    t = np.linspace(0, 2 * np.pi, MAX_ZONE_VERTICES, endpoint=False)
    poly = np.c_[np.cos(t), np.sin(t)]  # a circle: chords between interleaved points cross
    poly[[10, 11]] = poly[[11, 10]]  # so edges 9 (p9 p11) and 11 (p10 p12) cross
    assert self_intersection(poly) == (9, 11)
    with pytest.raises(ConfigError, match=r"intersects itself \(edges 9 and 11\)"):
        Zone("z", "energized", poly, (0.0, 1.0))


def _segments_cross_oracle(p1, p2, q1, q2) -> bool:
    """The pure-Python test the vectorised one replaced (touching and overlapping count)."""

    def cross(o, a, b) -> float:
        return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])

    d1, d2 = cross(q1, q2, p1), cross(q1, q2, p2)
    d3, d4 = cross(p1, p2, q1), cross(p1, p2, q2)
    if ((d1 > 0) != (d2 > 0)) and ((d3 > 0) != (d4 > 0)) and 0 not in (d1, d2, d3, d4):
        return True

    def on(a, b, c, d) -> bool:
        return (
            d == 0
            and min(a[0], b[0]) <= c[0] <= max(a[0], b[0])
            and min(a[1], b[1]) <= c[1] <= max(a[1], b[1])
        )

    return on(q1, q2, p1, d1) or on(q1, q2, p2, d2) or on(p1, p2, q1, d3) or on(p1, p2, q2, d4)


def _oracle(poly: np.ndarray) -> tuple[int, int] | None:
    V = len(poly)
    for i in range(V):
        for j in range(i + 2, V):
            if not (i == 0 and j == V - 1) and _segments_cross_oracle(
                poly[i], poly[(i + 1) % V], poly[j], poly[(j + 1) % V]
            ):
                return i, j
    return None


@settings(max_examples=300, deadline=None)
@given(
    pts=st.lists(st.tuples(st.integers(-3, 3), st.integers(-3, 3)), min_size=3, max_size=12),
    rows=st.integers(1, 5),
)
def test_self_intersection_matches_the_pairwise_oracle(pts, rows: int) -> None:
    # small integer grids: many collinear, touching and overlapping edges
    poly = np.array(pts, dtype=np.float64)
    assert self_intersection(poly, rows=rows) == _oracle(poly)


@st.composite
def site_dicts(draw) -> dict[str, Any]:
    """A good site with a few values made hostile (wrong types, NaN, huge, nested)."""
    site: dict[str, Any] = {"zones": [copy.deepcopy(ZONE) for _ in range(draw(st.integers(1, 2)))]}
    for k, z in enumerate(site["zones"]):
        z["name"] = f"z{k}"
    if draw(st.booleans()):
        site["fps"] = draw(numbers)
    for _ in range(draw(st.integers(0, 3))):
        zone = draw(st.sampled_from(site["zones"]))
        key = draw(
            st.sampled_from(
                [*sorted(ZONE), "joints", "margin_m", "dwell_s", "enter_s", "exit_s", "allowed"]
            )
        )
        # an earlier draw may have replaced the polygon or band by a hostile value already
        nested = isinstance(zone.get(key), list) and len(zone[key]) > 0
        if key in ("polygon", "z") and nested and draw(st.booleans()):
            target = zone[key] if key == "z" else draw(st.sampled_from(zone[key]))
            if isinstance(target, list) and len(target) >= 2:
                target[draw(st.integers(0, 1))] = draw(numbers | values)
            else:
                zone[key] = draw(numbers | values)
        else:
            zone[key] = draw(numbers | values)
    return site


@FUZZ
@given(site=site_dicts())
def test_site_files_load_checked_or_raise_config_error(tmp_path, site) -> None:
    path = tmp_path / "site.toml"
    path.write_text(toml_text(site), encoding="utf-8")
    try:
        loaded = load_site(path)
    except ConfigError as e:
        assert str(e).startswith(f"{path}: "), str(e)
        return
    assert loaded.fps is None or FPS_MIN <= loaded.fps <= FPS_MAX
    for z in loaded.zones:
        assert np.isfinite(z.polygon).all() and np.abs(z.polygon).max() <= SITE_LIMIT_M
        assert z.z[0] < z.z[1] and all(np.isfinite(z.z))
        assert all(v is None or 0 <= v <= 86400 for v in (z.margin_m, z.dwell_s, z.enter_s))


@FUZZ
@given(raw=st.binary(max_size=300))
def test_arbitrary_bytes_raise_config_error_only(tmp_path, raw: bytes) -> None:
    path = tmp_path / "site.toml"
    path.write_bytes(raw)
    with pytest.raises(ConfigError):  # no zones in almost all, and nothing else escapes
        load_site(path)


def test_zone_names_of_any_text_round_trip(tmp_path: Path) -> None:
    name = 'panel "A"\n\\ #1 \x7f'
    site = Site((Zone(name, "energized", np.array(ZONE["polygon"]), (0.0, 2.0)),), fps=30.0)
    save_site(tmp_path / "s.toml", site)
    assert load_site(tmp_path / "s.toml").zones[0].name == name
