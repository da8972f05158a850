"""The Site tab's surveyed points in the real browser over a real server, against a simulated
yard with known points: an admin types the points' coordinates, clicks each point in each
camera's picture, saves, solves (every camera placed, the bumped one's turn shown), accepts,
and the keeper applies the rig at the next step; a viewer sees the points but edits nothing."""

from __future__ import annotations

import shutil
from importlib import resources
from pathlib import Path

import pytest

from browsing import chromium, console_page
from consoled import console_server
from knocked import surveyed_yard
from stereopose.fence import load_site
from stereopose.site.health.calib_keeper import KeeperDesk
from stereopose.site.http.app import Desks
from stereopose.site.site_desk import SiteDesk
from waiting import wait_until

pytestmark = [pytest.mark.slow]

DEMO_SITE = Path(str(resources.files("stereopose") / "data" / "demo_site.toml"))


def test_an_admin_places_the_cameras_from_surveyed_points(tmp_path) -> None:
    truth, doc, clicks, keeper, applied = surveyed_yard(tmp_path)
    calibration = KeeperDesk()
    calibration.attach(keeper)
    path = tmp_path / "site.toml"
    shutil.copy(DEMO_SITE, path)
    site = SiteDesk(path, load_site(path), tmp_path / "history", rig=keeper.rig)
    desks = Desks(calibration=calibration, site=site)
    with console_server(tmp_path / "out", app_kw={"desks": desks}) as s, chromium() as browser:
        with console_page(browser, s.url, "ada", "survey-admin") as page:
            page.click('.tab[data-tab="site"]')
            wait_until(lambda: page.locator("#site-camera option").count() == len(truth), "views")
            lines = [f"{k} {x} {y} {z}" for k, (x, y, z) in doc["points"].items()]
            page.fill("#survey-points", "\n".join(lines))
            for cam in truth:
                page.select_option("#site-camera", cam.name)
                view = page.locator("#site-camera-svg")
                view.scroll_into_view_if_needed()
                box = view.bounding_box()  # in the viewport, as the mouse clicks
                for point, (u, v) in clicks[cam.name].items():
                    page.select_option("#survey-point", point)
                    x = box["x"] + u / cam.size[0] * box["width"]
                    y = box["y"] + v / cam.size[1] * box["height"]
                    page.mouse.click(x, y)
                marks = page.locator("#site-camera-svg .survey-mark").count()
                assert marks == len(clicks[cam.name]), cam.name
            page.click("#survey-save")
            wait_until(lambda: page.text_content("#survey-info") == "saved", "saved")
            page.click("#survey-solve")
            wait_until(
                lambda: page.locator("#survey-result tr").count() == len(truth) + 1, "solved"
            )
            rows = {
                r.get_attribute("data-camera"): [c.text_content() for c in r.locator("td").all()]
                for r in page.locator("#survey-result tr[data-camera]").all()
            }
            assert set(rows) == set(truth.names)
            assert all(float(r[1]) < 4.0 for r in rows.values()), rows  # error px
            assert 1.7 < float(rows["cam02"][3]) < 2.3  # the bumped camera turns back
            # the residuals beside the marks
            assert " px" in page.text_content("#site-camera-svg .survey-mark text")
            page.click("#survey-accept")
            wait_until(lambda: "next step" in page.text_content("#survey-info"), "accepted")
        events = keeper.update(1, 0.1, {}, [])
        assert [e.type for e in events] == ["calibration_corrected"] * len(truth)
        assert events[0].result["accepted_by"] == "ada" and len(applied) == 1
        with console_page(browser, s.url, "vera", "survey-viewer") as page:
            page.click('.tab[data-tab="site"]')
            wait_until(lambda: page.input_value("#survey-points").count("\n") >= 5, "the points")
            assert page.get_attribute("#survey-points", "readonly") is not None
            assert not page.is_visible("#survey-save") and not page.is_visible("#survey-solve")
