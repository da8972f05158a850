"""The console's Site tab in the real browser (Playwright + Debian's chromium) over a real
server and a real site file (the demo's): an admin draws a zone on the plan by clicking its
corners, names it, saves, and the service has the new site to take at its next step; the
versions are listed and an earlier one is restored; a viewer sees the tab and the zones but
has nothing to save, and no page error or CSP violation happens."""

from __future__ import annotations

import contextlib
import shutil
from importlib import resources
from pathlib import Path

import numpy as np
import pytest

from browsing import chromium, console_page
from consoled import console_server, demo_plan
from stereopose.fence import load_site
from stereopose.site.http.app import Desks
from stereopose.site.site_desk import SiteDesk
from waiting import wait_until

pytestmark = [pytest.mark.slow]

DEMO_SITE = Path(str(resources.files("stereopose") / "data" / "demo_site.toml"))


@pytest.fixture
def browser():
    with chromium() as b:
        yield b


@contextlib.contextmanager
def _page(browser, url: str, user: str):
    with console_page(browser, url, user, f"site-tab-{user}") as page:
        page.click('.tab[data-tab="site"]')
        page.wait_for_selector("#site-zones li", timeout=20_000)
        yield page


def _zones(page) -> list[str]:
    return page.evaluate(
        "[...document.querySelectorAll('#site-zones li')].map(n => n.dataset.zone)"
    )


def test_an_admin_draws_a_zone_saves_it_and_restores_the_earlier_version(browser, tmp_path):
    path = tmp_path / "site.toml"
    shutil.copy(DEMO_SITE, path)
    desk = SiteDesk(path, load_site(path), tmp_path / "history", rig=demo_plan(tmp_path).rig)
    first = desk.version
    with console_server(tmp_path / "out", app_kw={"desks": Desks(site=desk)}) as s:
        with _page(browser, s.url, "ada") as page:
            assert _zones(page) == ["overhead_busbar", "work_area", "qs1_front", "qs1_handle"]
            page.click("#site-new")
            box = page.locator("#site-plan").bounding_box()
            for fx, fy in ((0.15, 0.15), (0.3, 0.15), (0.3, 0.3)):
                page.mouse.click(box["x"] + fx * box["width"], box["y"] + fy * box["height"])
            page.click("#site-finish")
            wait_until(lambda: len(_zones(page)) == 5, "the drawn zone listed", poll_s=0.05)
            page.fill("#site-name", "bay_3")
            page.select_option("#site-kind", "restricted")
            page.click("#site-save")
            wait_until(lambda: desk.version != first, "the new site saved", poll_s=0.05)
            wait_until(
                lambda: (
                    "saved" in page.text_content("#site-info")
                    or "version" in page.text_content("#site-info")
                ),
                "the page saying so",
                poll_s=0.05,
            )
            change = desk.take()
            added = [z for z in change.new.zones if z.name == "bay_3"]
            assert change.by == "ada" and len(added) == 1 and added[0].kind == "restricted"
            assert len(added[0].polygon) == 3
            assert "bay_3" in path.read_text()
            # the demo's zones (in view of every camera) drawn in every camera's picture
            for name in ("cam01", "cam02", "cam03", "cam04"):
                page.select_option("#site-camera", name)
                wait_until(
                    lambda: (
                        {"overhead_busbar", "work_area", "qs1_front", "qs1_handle"}
                        <= set(
                            page.evaluate(
                                "[...document.querySelectorAll('#site-camera-svg g')]"
                                ".filter(g => g.querySelector('polyline')).map(g => g.dataset.zone)"
                            )
                        )
                    ),
                    f"the zones' prisms in {name}",
                    poll_s=0.05,
                )
            # a zone drawn on a camera's picture: its corners land on the floor there
            page.click("#site-new")
            picture = page.locator("#site-camera-svg")
            picture.scroll_into_view_if_needed()
            view = picture.bounding_box()
            for fx, fy in ((0.4, 0.8), (0.6, 0.8), (0.6, 0.9)):
                picture.click(position={"x": fx * view["width"], "y": fy * view["height"]})
            wait_until(
                lambda: page.evaluate("window.stereoposeConsole.site.drawing.length") == 3,
                "three corners from the picture",
                poll_s=0.05,
            )
            corners = page.evaluate("window.stereoposeConsole.site.drawing")
            page.click("#site-finish")
            wait_until(lambda: len(_zones(page)) == 6, "the zone from the picture", poll_s=0.05)
            from stereopose.site.site_views import floor_point

            cam = next(c for c in desk.rig if c.name == "cam04")
            clicked = [
                floor_point(cam, fx, fy, 0.0) for fx, fy in ((0.4, 0.8), (0.6, 0.8), (0.6, 0.9))
            ]
            # each corner where its ray meets the floor, snapped (a 5 cm grid, or another zone's
            # corner within 15 cm)
            assert np.linalg.norm(np.array(corners) - np.array(clicked), axis=1).max() <= 0.16
            page.click('#site-zones li[data-zone="zone_6"]')
            page.click("#site-delete")
            # the versions listed, the earlier one restored
            page.wait_for_selector(f'#site-history li[data-version="{first}"] button')
            page.click(f'#site-history li[data-version="{first}"] button')
            wait_until(lambda: desk.version == first, "the earlier version restored", poll_s=0.05)
            wait_until(lambda: len(_zones(page)) == 4, "the plan reloaded", poll_s=0.05)
        with _page(browser, s.url, "vera") as page:
            assert len(_zones(page)) == 4
            assert page.is_hidden("#site-save") and page.is_hidden("#site-new")
            page.click('#site-zones li[data-zone="work_area"]')
            assert page.is_disabled("#site-name")
            assert not page.query_selector_all("#site-history button")


def test_the_plan_shows_the_cameras_and_an_error_is_shown_at_its_field(browser, tmp_path):
    """The plan draws each camera with the floor it sees; a zone's joints and state source are
    set in the form; a bad margin saved is refused at the margin's field, the zone chosen."""
    plan = demo_plan(tmp_path)
    path = tmp_path / "site.toml"
    shutil.copy(DEMO_SITE, path)
    desk = SiteDesk(path, load_site(path), tmp_path / "history", rig=plan.rig)
    with console_server(tmp_path / "out", plan, app_kw={"desks": Desks(site=desk)}) as s:
        with _page(browser, s.url, "ada") as page:
            wait_until(
                lambda: page.locator("#site-plan .site-cameras [data-camera]").count() == 4,
                "the four cameras on the plan",
            )
            assert page.locator("#site-plan .site-cameras .fov").count() == 4
            page.click('#site-zones li[data-zone="overhead_busbar"]')
            page.fill("#site-joints", "left_wrist, right_wrist, nose")
            page.fill("#site-margin", "-1")
            page.click("#site-save")
            note = "#site-margin ~ .field-error, label:has(#site-margin) .field-error"
            wait_until(lambda: "margin_m" in (page.text_content(note) or ""), "at the field")
            assert "expected a finite number" in page.text_content(note)
            assert page.evaluate("document.activeElement.id") == "site-margin"
            page.fill("#site-margin", "0.4")
            page.click("#site-save")
            wait_until(lambda: desk.take() is not None or False, "saved", poll_s=0.05)
            # a drawing of the site under the plan, placed by two of its points
            import cv2

            drawing = tmp_path / "layout.png"
            cv2.imwrite(str(drawing), np.full((300, 400, 3), 200, np.uint8))
            page.set_input_files("#site-bg-file", str(drawing))
            page.fill("#site-bg-points", "10 290 0 0; 390 290 19 0")
            page.click("#site-bg-set")
            image = "#site-plan image.site-background"
            wait_until(lambda: page.locator(image).count() == 1, "the drawing on the plan")
            matrix = page.get_attribute(image, "transform")
            a, b, c, d, e, f = (float(v) for v in matrix[7:-1].split())
            assert (a, b, d) == pytest.approx((0.05, 0.0, 0.05)) and abs(c) < 1e-12
            assert (e, f) == pytest.approx((-0.5, -14.5))  # pixel (10, 290) on the site's (0, 0)
            assert desk.background.placement()["size"] == [400, 300]
        busbar = next(z for z in load_site(path).zones if z.name == "overhead_busbar")
        assert busbar.margin_m == 0.4 and len(busbar.joints) == 3


WARNINGS = """
[warnings]
language = "en"

[[speakers]]
name = "pa_bay1"
url = "rtp://239.10.0.1:5004"
zones = ["overhead_busbar"]

[[signals]]
name = "tower"
host = "127.0.0.1"
coils = { beacon = 0 }
zones = ["overhead_busbar"]
position = [1.0, 1.0]
"""


def test_an_admin_places_a_speaker_on_the_plan_and_names_the_zones_it_covers(browser, tmp_path):
    path = tmp_path / "site.toml"
    path.write_text(DEMO_SITE.read_text() + WARNINGS)
    desk = SiteDesk(path, load_site(path), tmp_path / "history")
    first = desk.version
    with console_server(tmp_path / "out", app_kw={"desks": Desks(site=desk)}) as s:
        with _page(browser, s.url, "ada") as page:
            page.wait_for_selector('#site-outputs li[data-output="pa_bay1"]')
            assert "(not placed)" in page.text_content('#site-outputs li[data-output="pa_bay1"]')
            assert page.locator('#site-plan g.site-output[data-output="tower"] line').count() == 1
            page.click('#site-outputs li[data-output="pa_bay1"]')
            assert "rtp://239.10.0.1:5004" in page.text_content("#site-output-what")
            page.click("#site-output-place")
            box = page.locator("#site-plan").bounding_box()
            page.mouse.click(box["x"] + 0.5 * box["width"], box["y"] + 0.5 * box["height"])
            page.wait_for_selector('#site-plan g.site-output[data-output="pa_bay1"] circle')
            page.check('#site-output-zones input[value="work_area"]')
            page.click("#site-save")
            wait_until(lambda: desk.version != first, "the new site saved", poll_s=0.05)
            change = desk.take()
            (pa,) = change.new.warnings.speakers
            assert pa.zones == ("overhead_busbar", "work_area") and pa.position is not None
            assert change.new.warnings.signals[0].position == (1.0, 1.0)  # left as it was
            assert "position" in path.read_text()
            # a place typed: the plan's mark follows
            page.click('#site-outputs li[data-output="tower"]')
            page.fill("#site-output-position", "-0.5 0.5")
            mark = '#site-plan g.site-output[data-output="tower"] rect'
            page.wait_for_function(f"document.querySelector('{mark}').getAttribute('y') < -0.4")
        with _page(browser, s.url, "vera") as page:
            page.wait_for_selector('#site-outputs li[data-output="tower"]')
            page.click('#site-outputs li[data-output="tower"]')
            assert page.is_hidden("#site-output-place")
            assert page.is_disabled("#site-output-position")
