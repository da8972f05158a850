"""Zones switched off and on while serving (site.site_desk.SiteDesk.switch_zone, taken by
site.site_switch at a step's start): whoever is inside exits and the zone says who switched it
off; no event of its own while off; switched on, people in it enter again."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from stereopose.config import Config
from stereopose.errors import ConfigError
from stereopose.fence import FenceMonitor, load_site
from stereopose.pipeline.incidents import SiteRules
from stereopose.pipeline.step_rules import step_chain
from stereopose.site.health.watch import CameraWatch
from stereopose.site.site_desk import MAX_SWITCHES, SiteDesk
from stereopose.site.site_switch import SiteSwitch
from stereopose.site.steps import ServeEvents
from stereopose.types import People3D

FPS = 25.0
SITE = """fps = 25.0

[[zones]]
name = "bay2"
kind = "energized"
polygon = [[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]]
z = [0.0, 2.0]
margin_m = 0.3

[[zones]]
name = "bench"
kind = "work_area"
polygon = [[3.0, 0.0], [4.0, 0.0], [4.0, 1.0], [3.0, 1.0]]
z = [0.0, 2.0]
"""


def _people(f: int, x: float | None) -> People3D:
    """Person 7 standing at (x, 0.5) at frame f (None: nobody)."""
    P = 0 if x is None else 1
    J = np.zeros((P, 17, 3))
    if P:
        J[0, :, 0], J[0, :, 1], J[0, :, 2] = x, 0.5, np.linspace(1.7, 0.05, 17)
    return People3D(
        f,
        J,
        np.ones((P, 17)),
        np.full(P, 7),
        np.zeros((P, 17)),
        np.full((P, 17), 2),
        np.full((P, 2), -1),
    )


@pytest.fixture
def served(tmp_path: Path):
    path = tmp_path / "site.toml"
    path.write_text(SITE)
    site = load_site(path)
    desk = SiteDesk(path, site, tmp_path / "history")
    fences = FenceMonitor(site, FPS)
    rules = SiteRules(step_chain(fences), fences)
    events = ServeEvents(CameraWatch(["cam"], 5.0, start=0.0), None)
    switch = SiteSwitch(desk, events, Config(fps=FPS))
    frame = [0]

    def step(x: float | None) -> list:
        """One step: the switches taken, then the person at x through the fences."""
        f = frame[0] = frame[0] + 1
        out, taken = switch(rules, f / FPS, f)
        assert taken is None  # a zone switched is no new site
        return out + fences.update(_people(f, x))

    return desk, step


def _types(events) -> list[str]:
    return [e.type for e in events]


def test_a_zone_switched_off_and_on_again(served) -> None:
    desk, step = served
    got = [e for _ in range(10) for e in step(0.5)]
    assert _types(got) == ["enter"]
    desk.switch_zone("bay2", False, "MQTT: control desk")
    exit_, off = step(0.5)
    assert (exit_.type, exit_.person, exit_.zone) == ("exit", 7, "bay2")
    assert exit_.source == "zone switched off by MQTT: control desk"
    assert (off.type, off.kind, off.zone) == ("zone_disabled", "service", "bay2")
    assert off.source == "MQTT: control desk: bay2 switched off"
    # off: walking out, in again, near it: nothing of the zone's own
    assert [e for x in [2.0] * 10 + [0.5] * 10 + [1.1] * 10 for e in step(x)] == []
    desk.switch_zone("bay2", False, "MQTT")  # off already: no second event
    assert step(0.5) == []
    desk.switch_zone("bay2", True, "MQTT")
    (on,) = step(0.5)
    assert (on.type, on.zone, on.source) == ("zone_enabled", "bay2", "MQTT: bay2 switched on")
    assert _types(e for _ in range(10) for e in step(0.5)) == ["enter"]  # a newcomer again


def test_an_unknown_zone_is_refused_and_switches_are_bounded(served) -> None:
    desk, _ = served
    with pytest.raises(ConfigError, match="no such zone"):
        desk.switch_zone("bay9", False, "MQTT")
    for k in range(MAX_SWITCHES + 5):  # no step takes them meanwhile: the oldest go, counted
        desk.switch_zone("bench", k % 2 == 1, "MQTT")
    assert desk.switches_dropped == 5
    assert len(desk.take_switches()) == MAX_SWITCHES
