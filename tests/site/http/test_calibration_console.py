"""The rig kept calibrated, in the console (real browser, real server): a pose proposed for a
knocked camera (calibration_auto = false) is shown under that camera's picture to every role;
only an admin has Accept, and a click has the service apply it at its next step."""

from __future__ import annotations

import pytest

from browsing import chromium, console_page
from consoled import console_server, demo_plan
from knocked import proposed_keeper
from stereopose.site.health.calib_keeper import KeeperDesk
from stereopose.site.http.app import Desks
from waiting import wait_until

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def proposed(tmp_path_factory):
    return proposed_keeper(tmp_path_factory.mktemp("calib"))


def _line(page, camera: str) -> tuple[str, str]:
    node = page.locator(f'.camera-card[data-camera="{camera}"] .camera-calibration')
    return node.get_attribute("data-state") or "", node.inner_text()


def test_an_admin_accepts_the_pose_proposed_for_a_knocked_camera(proposed, tmp_path) -> None:
    keeper, applied, steps = proposed
    desk = KeeperDesk()
    desk.attach(keeper)
    plan = demo_plan(tmp_path)  # its cam01..cam04 on the console's strip
    with (
        console_server(tmp_path / "out", plan, app_kw={"desks": Desks(calibration=desk)}) as s,
        chromium() as browser,
    ):
        with console_page(browser, s.url, "vera", "calibration-viewer") as page:
            # the cards may be drawn again (the cameras' list coming in) after a first
            # calibration line: wait for the proposal on the card as it stands
            wait_until(
                lambda: _line(page, "cam02")[0] == "proposed",
                "the proposal shown to a viewer",
                poll_s=0.1,
            )
            state, text = _line(page, "cam02")
            assert state == "proposed" and "new pose proposed: turned 1." in text
            assert page.locator(".accept-pose").count() == 0  # a viewer cannot accept
            assert _line(page, "cam01") == ("", "")
        with console_page(browser, s.url, "ada", "calibration-admin") as page:
            button = page.locator('.accept-pose[data-camera="cam02"]')
            button.wait_for()
            assert not applied
            button.click()
            wait_until(
                lambda: _line(page, "cam02")[0] == "accepted",
                "the pose shown accepted",
                poll_s=0.1,
            )
            assert "accepted by ada" in _line(page, "cam02")[1]
    # the service applies it at its next step
    events = keeper.update(len(steps), len(steps) * 0.08, steps[-1], [])
    assert [e.type for e in events] == ["calibration_corrected"] and applied
    assert events[0].result["accepted_by"] == "ada"
