"""A new site while serving is a new step object (site.site_switch.site_rules, taken whole by
pipeline.incidents.IncidentStep between two steps): the old site's rules are left as they were,
the new ones hold the new zones, fences and alarm settings, and only the declared state crosses
over (who is inside a zone kept as it was, the open incidents)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from stereopose.alarms import IncidentBook
from stereopose.config import Config
from stereopose.fence import load_site
from stereopose.pipeline.incidents import IncidentStep, SiteRules
from stereopose.site.health.watch import CameraWatch
from stereopose.site.site_desk import SiteDesk
from stereopose.site.site_switch import Outliving, SiteSwitch, site_changes, site_rules
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


def _people(f: int, x: float) -> People3D:
    """Person 7 standing at (x, 0.5) at frame f, stamped with its time."""
    J = np.zeros((1, 17, 3))
    J[0, :, 0], J[0, :, 1], J[0, :, 2] = x, 0.5, np.linspace(1.7, 0.05, 17)
    people = People3D(
        f,
        J,
        np.ones((1, 17)),
        np.full(1, 7),
        np.zeros((1, 17)),
        np.full((1, 17), 2),
        np.full((1, 2), -1),
    )
    return people.at(f / FPS)


@pytest.fixture
def served(tmp_path: Path):
    path = tmp_path / "site.toml"
    path.write_text(SITE)
    site = load_site(path)
    desk = SiteDesk(path, site, tmp_path / "history")
    events = ServeEvents(CameraWatch(["cam"], 5.0, start=0.0), None)
    cfg, kept = Config(fps=FPS), Outliving()
    rules = site_rules(site, events, cfg, kept)
    step = IncidentStep(
        IncidentBook(rules.settings),
        rules.chain,
        holding=rules.holding,
        clock=lambda: 0.0,
        switch=SiteSwitch(desk, events, cfg, kept=kept),
    )
    return desk, step


def _run(step: IncidentStep, frames: range, x: float) -> list:
    out = []
    for f in frames:
        out += step.step(f / FPS, f, _people(f, x))[0]
    return out


def test_a_new_site_is_built_whole_and_taken_between_two_steps(served) -> None:
    desk, step = served
    entered = [e for e in _run(step, range(1, 11), 0.5) if e.type == "enter"]
    assert [e.zone for e in entered] == ["bay2"] and entered[0].incident is not None
    incident = entered[0].incident
    first = step.rules
    first_monitor, first_rules = first.holding, list(first.chain.rules)
    assert first_monitor is not None

    doc = desk.current()["site"]
    assert isinstance(doc, dict)
    zones = doc["zones"]
    zones[0]["priority"] = 1  # bay2 tests people as before; its incidents more urgent
    zones.append({**zones[1], "name": "pit", "polygon": [[5, 0], [6, 0], [6, 1], [5, 1]]})
    desk.put(doc, desk.version, "admin")

    events = _run(step, range(11, 12), 0.5)
    (changed,) = [e for e in events if e.type == "site_changed"]
    assert "added pit" in changed.source and "changed bay2" in changed.source
    # the step's site is a new object; the old one is as it was, nothing set on it
    assert isinstance(step.rules, SiteRules) and step.rules is not first
    assert first.holding is first_monitor and first.chain.rules == first_rules
    assert step.monitor is not first_monitor and step.monitor is not None
    assert [z.name for z in step.monitor.zones] == ["bay2", "bench", "pit"]
    assert step.rules.settings is not None and step.book.settings is step.rules.settings
    with pytest.raises(dataclasses.FrozenInstanceError):  # swapped whole, never patched
        step.rules.chain = first.chain  # type: ignore[misc]  # frozen on purpose
    # the declared state crossed over: person 7 is still inside bay2 (no new enter), and the
    # incident its entry opened is still the one open
    later = _run(step, range(12, 30), 0.5)
    assert not [e for e in later if e.type == "enter"]
    assert step.book.get(incident).state != "closed"
    out = [e for e in _run(step, range(30, 50), 2.0) if e.type == "exit"]
    assert [e.zone for e in out] == ["bay2"]  # one exit: the person's, from the carried state


def test_a_zone_is_changed_when_any_of_its_fields_is(tmp_path: Path) -> None:
    path = tmp_path / "site.toml"
    path.write_text(SITE)
    old = load_site(path)
    assert site_changes(old, load_site(path)) == ([], [], [])  # read again: the same zones
    bay2, bench = old.zones
    louder = dataclasses.replace(bay2, priority=1)
    assert louder.tests_alike(bay2) and not louder.same_as(bay2)
    moved = dataclasses.replace(bay2, polygon=bay2.polygon + 0.5)
    assert not moved.tests_alike(bay2) and not moved.same_as(bay2)
    new = dataclasses.replace(old, zones=(louder, bench))
    assert site_changes(old, new) == ([], [], ["bay2"])
