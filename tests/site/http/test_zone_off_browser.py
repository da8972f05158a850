"""A zone switched off over MQTT, as the console shows it (the real server, live hub and
browser): the plan draws it apart and labels it switched off, and back as it was once on."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from browsing import chromium, console_page
from consoled import WALL_START, console_server, demo_plan, zone_event
from stereopose.io.sinks.base import FrameResult
from stereopose.types import People3D
from waiting import wait_until

pytestmark = [pytest.mark.realdata, pytest.mark.slow]

ZONE = "work_area"
LABEL = f'#floor-zones g[data-zone="{ZONE}"]'


def _frame(k: int, events=()) -> FrameResult:
    nobody = People3D(
        k,
        np.zeros((0, 17, 3)),
        np.zeros((0, 17)),
        np.zeros(0),
        np.zeros((0, 17)),
        np.zeros((0, 17)),
        np.zeros((0, 4)),
    )
    return FrameResult(k, k / 30.0, {}, nobody, tuple(events))


def test_the_plan_shows_a_zone_switched_off_and_on_again(tmp_path: Path) -> None:
    plan = demo_plan(tmp_path)
    with console_server(tmp_path / "out", plan) as served, chromium() as browser:
        hub = served.console.hub
        hub.on_frame(_frame(1), WALL_START)
        with console_page(browser, served.url, "vera", "zone-off") as page:
            page.wait_for_selector(LABEL, timeout=30_000)
            assert "zone-off" not in page.get_attribute(LABEL, "class")
            off = zone_event(2, "zone_disabled", person=-1, zone=ZONE, kind="service")
            hub.on_frame(_frame(2, [off]), WALL_START)

            def label() -> str:
                return page.text_content(f"{LABEL} text") or ""

            wait_until(lambda: "[switched off]" in label(), "the zone shown off", timeout_s=20)
            assert "zone-off" in page.get_attribute(LABEL, "class")
            assert page.get_attribute(LABEL, "data-state") == "off"
            on = zone_event(3, "zone_enabled", person=-1, zone=ZONE, kind="service")
            hub.on_frame(_frame(3, [on]), WALL_START)
            wait_until(lambda: "[switched off]" not in label(), "on again", timeout_s=20)
            assert page.get_attribute(LABEL, "data-state") == "free"
