"""The control room's console in the real browser (Playwright + Debian's chromium) on a real
`stereopose control-room` process fed by two sites (real incident books and event logs, their
outboxes) through a real mosquitto: an operator logs in, sees both sites at a glance with their
open incidents, one incident feed naming the site, acknowledges one, sees it on its way and
then acknowledged as the site recorded it; a site's page shows its zones and a link to its
console. A viewer has no Ack button. No console error, no request leaving 127.0.0.1, under the
page's own Content-Security-Policy (so waits poll page.evaluate)."""

from __future__ import annotations

import os
import shutil
import signal
from urllib.parse import urlsplit

import pytest
from test_control_room import _add, _add_user, _client, _config, _enrol, _start
from test_incidents import Site

from brokers import Broker, free_port
from waiting import wait_until

pytestmark = pytest.mark.slow

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
ARGS = [
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-sync",
    "--disable-background-networking",
    "--disable-component-update",
]


@pytest.fixture(scope="module")
def browser():
    if CHROMIUM is None:
        if os.environ.get("STEREOPOSE_REQUIRE_BROWSER") == "1":
            pytest.fail("chromium not found; install Debian's chromium package")
        pytest.skip("chromium not installed (Debian package chromium)")
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        b = p.chromium.launch(executable_path=CHROMIUM, args=ARGS)
        yield b
        b.close()


def _login(browser, base: str, user: str, password: str, seen: dict):
    context = browser.new_context(viewport={"width": 1500, "height": 900})
    page = context.new_page()
    page.on("console", lambda m: seen["problems"].append(m.text) if m.type == "error" else None)
    page.on("pageerror", lambda e: seen["problems"].append(f"page error: {e}"))
    page.on("request", lambda r: seen["requests"].append(r.url))
    page.goto(base + "/")
    page.wait_for_selector("#login-form", state="visible", timeout=20_000)
    page.fill("#login-user", user)
    page.fill("#login-password", password)
    page.click("#login-submit")
    page.wait_for_selector("#console", state="visible", timeout=60_000)
    return context, page


def _eval(page, script: str, arg=None):
    return page.evaluate(script, arg)


def test_the_control_rooms_console_in_a_browser(browser, tmp_path):
    broker = Broker(tmp_path / "broker").start()
    http_port = free_port()
    config = _config(
        tmp_path / "room", broker.port, http_port, "[control_room]\ncommand_resend_s = 0.5\n"
    )
    _add_user(config)  # vera, a viewer
    _add(config, "olga", "operator")
    _enrol(config, "north", "south")
    plan = {
        "zones": [
            {"name": "busbar", "kind": "energized", "polygon": [[0, 0], [3, 0], [3, 1], [0, 1]]}
        ],
        "console_url": "http://127.0.0.1:1/",
    }
    north = Site(tmp_path, broker.port, "north", plan=plan)
    south = Site(tmp_path, broker.port, "south")
    proc = _start(config, tmp_path / "room.log")
    seen: dict = {"problems": [], "requests": []}
    try:
        c = _client(http_port)
        n_inc, _ = north.enter(), south.enter()
        wait_until(
            lambda: len(c.get("/api/incidents").json()["incidents"]) == 2,
            "both incidents in the control room",
            timeout_s=30,
        )
        base = f"http://127.0.0.1:{http_port}"
        ctx, page = _login(browser, base, "olga", "olga-password", seen)
        wait_until(
            lambda: _eval(page, "document.querySelectorAll('#sites-body tr').length") == 2,
            "both sites listed",
            timeout_s=20,
        )
        row = _eval(page, "[...document.querySelectorAll('#sites-body tr')].map(r => r.innerText)")
        assert any("north" in r and "live" in r for r in row), row
        line = f'#room-feed li[data-site="north"][data-incident="{n_inc}"]'
        wait_until(
            lambda: _eval(page, "(s) => !!document.querySelector(s + ' .ack-button')", line),
            "north's incident with its Ack",
            timeout_s=20,
        )
        assert "north" in page.inner_text(line)
        assert _eval(page, "document.getElementById('alarm-count').textContent") == "2"
        page.click(f"{line} .ack-button")
        wait_until(
            lambda: north.record(n_inc).acked_by == "olga via control-room",
            "the ack at the site",
            timeout_s=30,
        )
        north.run()
        wait_until(
            lambda: "acknowledged by olga via control-room" in page.inner_text(line),
            "the ack shown as the site recorded it",
            timeout_s=30,
        )
        wait_until(
            lambda: _eval(page, "document.getElementById('alarm-count').textContent") == "1",
            "one left unacknowledged",
            timeout_s=20,
        )
        # the site's page: its zones, and a link to its console
        page.click('#sites-body tr[data-site="north"]')
        wait_until(
            lambda: _eval(page, "document.querySelectorAll('#site-zones [data-zone]').length") == 1,
            "north's zones",
            timeout_s=20,
        )
        assert _eval(page, "document.getElementById('site-console').href") == plan["console_url"]
        ctx.close()
        ctx, page = _login(browser, base, "vera", "vera-password", seen)
        wait_until(
            lambda: _eval(page, "document.querySelectorAll('#room-feed li').length") == 2,
            "the viewer's feed",
            timeout_s=20,
        )
        assert _eval(page, "document.querySelectorAll('#room-feed .ack-button').length") == 0
        ctx.close()
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.wait(timeout=30)
        north.close()
        south.close()
        broker.stop()
    assert seen["problems"] == []
    outside = [u for u in seen["requests"] if urlsplit(u).hostname != "127.0.0.1"]
    assert seen["requests"] and outside == []
