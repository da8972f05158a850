"""The report opened in headless Chromium: no console errors, nothing fetched, a 3D view."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import numpy as np
import pytest

pytestmark = [pytest.mark.realdata, pytest.mark.slow]

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


def test_report_in_chromium_shows_the_3d_view(browser, real_demo_dir: Path, tmp_path: Path):
    page = browser.new_page(viewport={"width": 1300, "height": 900})
    problems: list[str] = []
    requests: list[str] = []
    page.on("console", lambda m: problems.append(m.text) if m.type == "error" else None)
    page.on("pageerror", lambda e: problems.append(str(e)))
    page.on("request", lambda r: requests.append(r.url))
    url = (real_demo_dir / "report.html").as_uri()
    page.goto(url)
    page.wait_for_selector("#view3d .main-svg", timeout=60_000)
    page.wait_for_selector("#floor .main-svg", timeout=60_000)
    page.wait_for_selector("#timeline .main-svg", timeout=60_000)
    shot = tmp_path / "view3d.png"
    page.locator("#view3d").screenshot(path=str(shot))
    people = page.evaluate(
        "document.getElementById('view3d').data"
        ".filter(t => t.name.startsWith('id ') && t.x.length > 0).map(t => t.name)"
    )
    frames = page.evaluate("document.getElementById('view3d')._transitionData._frames.length")
    page.close()
    assert problems == []
    assert requests == [url]  # self-contained: nothing else is fetched
    assert len(people) >= 2 and frames >= 50
    import cv2

    img = cv2.imread(str(shot))
    assert img is not None and img.shape[0] > 400
    # the people are drawn in their colours (id 1 orange, id 2 green in BGR)
    for bgr in ((14, 127, 255), (44, 160, 44)):
        close = np.abs(img.astype(int) - bgr).sum(axis=2) < 60
        assert close.sum() > 50, f"no pixels of colour {bgr} in the 3D view"


def test_report_of_a_run_cut_mid_line(real_demo_dir: Path, tmp_path: Path, caplog) -> None:
    from stereopose.viz.report import write_report

    run = tmp_path / "run"
    shutil.copytree(real_demo_dir, run, ignore=shutil.ignore_patterns("overlays", "trc"))
    text = (run / "poses3d.jsonl").read_text()
    (run / "poses3d.jsonl").write_text(text[: len(text) // 2])  # killed mid-line
    write_report(run)
    assert "1 damaged line(s) skipped" in caplog.text  # the cut line, counted
    page = (run / "report.html").read_text()
    assert "3D view" in page
    # the demo detects in regions (the default): each camera's cost against whole frames
    import json

    summary = json.loads((run / "summary.json").read_text())
    regions, carry = summary["regions"], summary["carry"]
    assert set(regions) == {"cam01", "cam02", "cam03", "cam04"}
    # every step of a camera either detected (in regions or its whole frame) or carried
    assert all(r["full_scans"] >= 1 for r in regions.values())
    assert all(r["steps"] == carry[c]["detected"] for c, r in regions.items()), (regions, carry)
    assert all(carry[c]["detected"] + carry[c]["carried"] == 100 for c in regions), carry
    assert "model input of whole frames&#x27;" in page and "newcomers: motion / scan" in page
