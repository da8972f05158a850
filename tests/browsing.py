"""The real browser for the console's tests: Debian's chromium driven by Playwright, and a
page logged in as one of the console's users that fails the test on a page error, a dialog or
a Content-Security-Policy violation (and leaves a screenshot)."""

from __future__ import annotations

import contextlib
import os
import shutil
from collections.abc import Iterator
from pathlib import Path

import pytest

from consoled import PASSWORDS

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
ARGS = ["--no-sandbox", "--disable-gpu", "--no-first-run", "--disable-sync"]
ROOT = Path(__file__).resolve().parents[1]
SHOTS = Path(os.environ.get("STEREOPOSE_SCREENSHOTS", ROOT / "out" / "console-screenshots"))
WATCH = """
window.__violations = [];
document.addEventListener('securitypolicyviolation', (e) => {
  window.__violations.push(`${e.violatedDirective} ${e.sourceFile}:${e.lineNumber}`);
});
"""


@contextlib.contextmanager
def chromium() -> Iterator:
    """The browser (a test fails without it where CI requires it, else skips)."""
    if CHROMIUM is None:
        if os.environ.get("STEREOPOSE_REQUIRE_BROWSER") == "1":
            pytest.fail("chromium not found; install Debian's chromium package")
        pytest.skip("chromium not installed (Debian package chromium)")
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        b = p.chromium.launch(executable_path=CHROMIUM, args=ARGS)
        try:
            yield b
        finally:
            b.close()


@contextlib.contextmanager
def console_page(browser, url: str, user: str, shot: str) -> Iterator:
    """The console at `url` logged in as `user`; screenshot `<shot>.png` at the end."""
    context = browser.new_context(viewport={"width": 1500, "height": 950})
    context.add_init_script(WATCH)
    page = context.new_page()
    problems: list[str] = []
    page.on("pageerror", lambda e: problems.append(f"page error: {e}"))
    page.on("dialog", lambda d: (problems.append(f"dialog: {d.message}"), d.dismiss()))
    page.goto(url + "/")
    page.wait_for_selector("#login-form", state="visible", timeout=20_000)
    page.fill("#login-user", user)
    page.fill("#login-password", PASSWORDS[user])
    page.click("#login-submit")
    page.wait_for_selector("#console", state="visible", timeout=60_000)
    try:
        yield page
        assert problems == [], problems
        violations = page.evaluate("window.__violations")
        assert violations == [], violations
    finally:
        with contextlib.suppress(Exception):
            SHOTS.mkdir(parents=True, exist_ok=True)
            page.screenshot(path=str(SHOTS / f"{shot}.png"))
        context.close()
