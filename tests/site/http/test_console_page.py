"""The console page's files, read as the browser will under the page's Content-Security-Policy
(default-src 'self', no inline script or style): nothing inline, nothing from elsewhere, every
file it names present, and the plotly bundle still one whose inline style sheets the page
knows how to turn off (tests/site/http/test_console_browser.py runs it for real)."""

from __future__ import annotations

import re
from html.parser import HTMLParser
from pathlib import Path

from stereopose.site.http.api.page import CONSOLE_DIR, plotly_js


class _Tags(HTMLParser):
    def __init__(self) -> None:
        super().__init__()
        self.tags: list[tuple[str, dict[str, str | None]]] = []
        self.data_in: dict[str, str] = {}
        self._open: list[str] = []

    def handle_starttag(self, tag: str, attrs: list) -> None:
        self.tags.append((tag, dict(attrs)))
        self._open.append(tag)

    def handle_endtag(self, tag: str) -> None:
        if self._open and self._open[-1] == tag:
            self._open.pop()

    def handle_data(self, data: str) -> None:
        if self._open and self._open[-1] in ("script", "style"):
            self.data_in[self._open[-1]] = self.data_in.get(self._open[-1], "") + data


def _page() -> _Tags:
    tags = _Tags()
    tags.feed((CONSOLE_DIR / "index.html").read_text(encoding="utf-8"))
    return tags


def test_the_page_has_no_inline_script_style_or_handler():
    page = _page()
    assert page.data_in.get("script", "").strip() == ""
    assert not any(tag == "style" for tag, _ in page.tags)
    for tag, attrs in page.tags:
        assert "style" not in attrs, f"<{tag}> has a style attribute"
        handlers = [a for a in attrs if a.startswith("on")]
        assert handlers == [], f"<{tag}> has inline handlers {handlers}"
    scripts = [a.get("src") for tag, a in page.tags if tag == "script"]
    assert scripts == ["/console/console.js"]


def test_every_file_the_page_names_is_there_and_local():
    page = _page()
    urls = [a[k] for _, a in page.tags for k in ("src", "href") if a.get(k)]
    assert urls
    for url in urls:
        assert url.startswith("/") and not url.startswith("//"), url
        if url.startswith("/console/"):
            assert (CONSOLE_DIR / url.removeprefix("/console/")).is_file(), url
    # the modules' imports, and the assets the scripts load
    for js in CONSOLE_DIR.glob("*.js"):
        text = js.read_text(encoding="utf-8")
        for name in re.findall(r'from "\./([\w.-]+)"', text):
            assert (CONSOLE_DIR / name).is_file(), f"{js.name} imports {name}"
        for url in re.findall(r'"(/console/[\w./-]+)"', text):
            assert (CONSOLE_DIR / url.removeprefix("/console/")).is_file() or url.endswith(
                "plotly.min.js"
            ), f"{js.name} names {url}"
        assert "innerHTML" not in text and "eval(" not in text, js.name


def test_the_plotly_bundle_adds_no_inline_style_the_page_does_not_turn_off():
    bundle = plotly_js()
    assert bundle is not None, "plotly.min.js not found in the plotly package"
    text = bundle.read_text(encoding="utf-8")
    page = _page()
    ids = {a.get("id") for _, a in page.tags if a.get("id")}
    # plotly skips its global style sheet when an element of this id and class exists
    assert "no-inline-styles" in text and "plotly.js-style-" in text
    link = next(a for t, a in page.tags if a.get("id") == "plotly.js-style-global")
    assert link.get("class") == "no-inline-styles" and link.get("href") == "/console/plotly.css"
    # every other inline <style> the bundle makes is guarded by an element id the page has
    guards = re.findall(
        r'getElementById\("([0-9a-f]{64})"\)\)\{var \w=document\.createElement\('
        r'"style"\)',
        text,
    )
    assert guards and set(guards) <= ids, f"plotly's style ids {guards} not in the page"
    assert Path(CONSOLE_DIR / "plotly.css").read_text().count(".js-plotly-plot") > 20


def test_both_consoles_log_in_through_one_module():
    """The login flow (the form, the session found again, a logout) is login.js's alone: the
    site's console and the control room's use it, neither asks the login endpoints itself."""
    room = CONSOLE_DIR.parents[2] / "controlroom" / "console" / "room.js"
    consoles = [*CONSOLE_DIR.glob("*.js"), room]
    asking = [
        js.name
        for js in consoles
        if js.name not in ("login.js", "api.js")
        and re.search(r"api\.(login|logout|me|hasSessionCookie)\(", js.read_text("utf-8"))
    ]
    assert asking == []
    assert 'from "./login.js"' in (CONSOLE_DIR / "console.js").read_text("utf-8")
    assert 'from "/console/login.js"' in room.read_text("utf-8")
