"""The Live tab's "On site" panel in the real browser over a real server, with real outputs (a
speaker paging a UDP listener, a pymodbus IO module): what sounds and why, each output's
health; an admin silences the beacon with a reason and the service has it; a viewer sees
the silence and has no button."""

from __future__ import annotations

from pathlib import Path

import pytest
from test_warnings_api import _people, warned_site

from browsing import chromium, console_page
from consoled import console_server
from modbus_device import IoModule
from rtp_listener import Listener
from stereopose.fence import FenceMonitor
from stereopose.onsite.service import OnSite
from stereopose.site.http.api.warnings import WarningsDesk
from stereopose.site.http.app import Desks
from waiting import wait_until

pytestmark = [pytest.mark.slow]


def test_the_panel_shows_what_sounds_and_an_admin_silences_the_beacon(tmp_path: Path) -> None:
    ear, module = Listener(), IoModule().start()
    site = warned_site(ear.port, module.port)
    onsite, fences, desk = OnSite(site), FenceMonitor(site, fps=20.0), WarningsDesk()
    desk.attach(onsite)
    for frame in range(5):  # a hand near the busbar
        p = _people(frame, True)
        fences.update(p)
        onsite.step(p.t, frame, p, fences)
    row = '#onsite-outputs li[data-output="{}"]'
    try:
        with (
            console_server(tmp_path, app_kw={"desks": Desks(warnings=desk)}) as served,
            chromium() as browser,
        ):
            with console_page(browser, served.url, "ada", "onsite-admin") as page:
                page.wait_for_selector(row.format("tower"), timeout=30_000)
                pa = page.text_content(row.format("pa"))
                assert "person 1 near busbar" in pa and "not verifiable" in pa
                wait_until(lambda: module.coils(0) == [True], "the beacon lit")
                page.fill(f"{row.format('tower')} .onsite-reason", "<b>lamp</b> replaced")
                page.select_option(f"{row.format('tower')} .onsite-minutes", "60")
                page.click(f"{row.format('tower')} .onsite-silence button")
                page.wait_for_selector(f'{row.format("tower")}[data-silenced="true"]')
                silenced = page.text_content(f"{row.format('tower')} .onsite-silenced")
                assert "by ada: <b>lamp</b> replaced" in silenced  # as text, never markup
                (s,) = onsite.controls.silenced().values()
                assert (s.output, s.by, round(s.until - s.since)) == ("tower", "ada", 3600)
            with console_page(browser, served.url, "vera", "onsite-viewer") as page:
                page.wait_for_selector(f'{row.format("tower")}[data-silenced="true"]')
                assert page.locator("#onsite .onsite-actions").count() == 0
    finally:
        onsite.close()
        module.stop()
