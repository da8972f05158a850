"""Names are data in every tab of the console: a real server (the real live hub, event log and
console routes) over the demo's rig and site renamed with hostile names, seen in the real
browser (Playwright + Debian's chromium).

Zones named with markup (`<b>`, `<a href>`, `<img onerror>`, `<span style>`, quotes and an
entity), cameras named with `?`, `#`, `/`, `%` and `<`, a behaviour rule and an event type
with markup: in the floor plan, the feed, the camera strip, the 3D view (plotly: its legend,
its labels) and the history, each name is shown literally as text, no element is made from
it, no dialog opens, every camera's picture loads, and no `securitypolicyviolation` fires on
any tab (the page's CSP has no 'unsafe-inline'). One served site and one page for all.
"""

from __future__ import annotations

import contextlib
import dataclasses
import os
import shutil
import threading
from collections.abc import Iterator
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from consoled import PASSWORDS, WALL_START, console_server, demo_plan
from stereopose.fence import Site
from stereopose.io.sinks.base import FrameResult
from stereopose.types import Event, People3D, Rig
from waiting import wait_until

pytestmark = [pytest.mark.realdata, pytest.mark.slow]

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
ARGS = [
    "--no-sandbox",
    "--disable-gpu",
    "--no-first-run",
    "--disable-sync",
    "--disable-background-networking",
    "--disable-component-update",
]
ROOT = Path(__file__).resolve().parents[2]
SHOTS = Path(os.environ.get("STEREOPOSE_SCREENSHOTS", ROOT / "out" / "console-screenshots"))

ZONES = [
    "<b>bold</b>",
    '<a href="http://x/">link</a>',
    "<img src=x onerror=alert(1)>",
    "\"quoted' &amp;",
    '<span style="font-size:40px">big</span>',
]
CAMERAS = ["cam?01&x=%41", "cam#02", "cam/03", "<i>cam04</i>"]
RULE = "<b>fall rule</b>"
ODD_TYPE = "<i>odd</i>"
USER = "otto"  # an operator (consoled.ROLES)

# a real person of the demo (served, frame 3): joints in metres, COCO order
JOINTS = [
    [0.02, -0.405, 1.262],
    [0.03, -0.437, 1.287],
    [0.034, -0.381, 1.29],
    [0.169, -0.447, 1.258],
    [0.087, -0.339, 1.266],
    [0.249, -0.478, 1.114],
    [0.134, -0.281, 1.109],
    [0.29, -0.573, 0.918],
    [0.169, -0.2, 0.905],
    [0.307, -0.554, 0.748],
    [0.186, -0.193, 0.753],
    [0.269, -0.453, 0.719],
    [0.243, -0.299, 0.708],
    [0.25, -0.468, 0.405],
    [0.259, -0.282, 0.417],
    [0.272, -0.508, 0.081],
    [0.231, -0.353, 0.064],
]

# what the page saw: set before any of its scripts runs (Playwright's init script is not
# subject to the page's CSP); a violation's report is kept with what it was about
WATCH = """
window.__violations = [];
document.addEventListener('securitypolicyviolation', (e) => {
  window.__violations.push(`${e.violatedDirective} ${e.blockedURI} ${e.sourceFile}:` +
                           `${e.lineNumber} ${e.sample}`);
});
"""

# elements that markup in a name would have made (plotly turns <b>, <i> and <span style>
# into tspans with a style attribute, <a> into an SVG <a>)
MADE = """() => {
  const shown = document.getElementById('console');
  const found = [];
  for (const node of shown.querySelectorAll('*')) {
    const tag = node.tagName.toLowerCase();
    const style = node.getAttribute('style') || '';
    if (['b', 'i', 'a', 'img', 'span', 'tspan', 'text'].includes(tag) &&
        /bold|italic|40px/.test(style)) found.push(`${tag} style=${style}`);
    if (['b', 'i'].includes(tag)) found.push(tag);
    if (tag === 'a' && !['h-csv', 'player-download', 't-report'].includes(node.id) &&
        !node.classList.contains('t-clip')) found.push('a');
    if (tag === 'img' && !node.dataset.camera &&
        !['player-frames', 'site-camera-img'].includes(node.id)) found.push('img');
  }
  return found;
}"""


def hostile_plan(folder: Path) -> SimpleNamespace:
    """The demo's rig and site, each camera and zone renamed (the geometry unchanged; the
    zones beyond the demo's busbar and work area are those two moved along x)."""
    plan = demo_plan(folder)
    rig = Rig(tuple(dataclasses.replace(c, name=n) for c, n in zip(plan.rig, CAMERAS, strict=True)))
    demo = plan.site.zones[:2]  # an energized zone, then a work area
    zones = []
    for i, name in enumerate(ZONES):
        base = demo[i % len(demo)]
        moved = base.polygon + np.array([2.5 * i, 0.0])
        zones.append(dataclasses.replace(base, name=name, polygon=moved))
    return SimpleNamespace(rig=rig, site=Site(tuple(zones)))


def _frame(frame: int, events=(), images=None) -> FrameResult:
    joints = np.asarray(JOINTS)[None] + [-0.5, 0.0, 0.0]
    people = People3D(
        frame=frame,
        joints=joints,
        conf=np.ones((1, 17)),
        ids=np.array([7]),
        reprojection_px=np.zeros((1, 17)),
        views=np.full((1, 17), 4),
        detections=np.zeros((1, 4), dtype=int),
    )
    return FrameResult(frame, frame / 30.0, {}, people, tuple(events), images)


def _events() -> list[Event]:
    """One event of each kind that names something: a zone's, a camera's, a rule's, an odd
    type's."""
    out = []
    for i, zone in enumerate(ZONES):
        kind = "energized" if i % 2 == 0 else "work_area"
        out.append(
            Event(
                t=1.0 + i,
                frame=30 + 30 * i,
                person=7,
                zone=zone,
                kind=kind,
                type="enter",
                onset_t=1.0 + i,
                position=(0.1, -0.2),
            )
        )
    for i, camera in enumerate(CAMERAS):
        out.append(
            Event(
                t=10.0 + i,
                frame=300 + 30 * i,
                person=-1,
                zone="",
                kind="camera",
                type="camera_down",
                onset_t=10.0 + i,
                camera=camera,
            )
        )
    out.append(
        Event(
            t=20.0,
            frame=600,
            person=7,
            zone="",
            kind="behaviour",
            type="person_down",
            onset_t=20.0,
            rule=RULE,
            posture="lying",
        )
    )
    out.append(
        Event(
            t=21.0,
            frame=630,
            person=7,
            zone=ZONES[1],
            kind="work_area",
            type=ODD_TYPE,
            onset_t=21.0,
        )
    )
    return out


@contextlib.contextmanager
def _frames(served, plan) -> Iterator[None]:
    """Frames at 5 a second as the frame loop would give them: every camera's image (so its
    picture is drawn) and health, the person inside the zones (entered at the first)."""
    hub, stop = served.console.hub, threading.Event()
    image = np.full((1920, 1088, 3), 90, np.uint8)
    image[600:1200, 300:800] = (0, 128, 255)
    images = {c.name: image for c in plan.rig}

    def feed() -> None:
        frame = 0
        while not stop.is_set():
            enter = (
                [
                    Event(
                        t=frame / 30.0,
                        frame=frame,
                        person=7,
                        zone=z.name,
                        kind=z.kind,
                        type="enter",
                        onset_t=frame / 30.0,
                    )
                    for z in plan.site.zones
                ]
                if frame == 0
                else []
            )
            for c in plan.rig:
                served.state.camera_frame(c.name)
            hub.on_frame(_frame(frame, enter, images), WALL_START)
            frame += 6
            stop.wait(0.2)

    thread = threading.Thread(target=feed, name="test-frames", daemon=True)
    thread.start()
    try:
        yield
    finally:
        stop.set()
        thread.join(5)


@pytest.fixture(scope="module")
def served(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("names")
    plan = hostile_plan(tmp)
    with console_server(tmp / "out", plan) as s:
        s.db.write_events(_events())
        with _frames(s, plan):
            yield s


@pytest.fixture(scope="module")
def page(served):
    if CHROMIUM is None:
        if os.environ.get("STEREOPOSE_REQUIRE_BROWSER") == "1":
            pytest.fail("chromium not found; install Debian's chromium package")
        pytest.skip("chromium not installed (Debian package chromium)")
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=ARGS)
        context = browser.new_context(viewport={"width": 1600, "height": 1000})
        context.add_init_script(WATCH)
        page = context.new_page()
        page.problems = []
        page.on("dialog", lambda d: (page.problems.append(f"dialog: {d.message}"), d.dismiss()))
        page.on("pageerror", lambda e: page.problems.append(f"page error: {e}"))
        page.on(
            "console",
            lambda m: page.problems.append(f"console: {m.text}") if m.type == "error" else None,
        )
        page.goto(served.url + "/")
        page.wait_for_selector("#login-form", state="visible", timeout=20_000)
        page.fill("#login-user", USER)
        page.fill("#login-password", PASSWORDS[USER])
        page.click("#login-submit")
        page.wait_for_selector("#console", state="visible", timeout=60_000)
        try:
            yield page
        finally:
            with contextlib.suppress(Exception):  # the last view, to see what a failure saw
                SHOTS.mkdir(parents=True, exist_ok=True)
                page.screenshot(path=str(SHOTS / "hostile-names.png"))
            browser.close()


def _clean(page, tab: str) -> None:
    """Nothing made from a name, no CSP violation, no dialog, no error, on `tab`."""
    assert page.evaluate(MADE) == [], tab
    assert page.evaluate("window.__violations") == [], tab
    assert page.problems == [], tab


def _texts(page, selector: str) -> list[str]:
    return page.evaluate(f"[...document.querySelectorAll({selector!r})].map(n => n.textContent)")


def test_hostile_names_are_text_in_every_tab(page, served):
    # live: the floor plan (SVG), the feed, the camera strip with every picture
    wait_until(
        lambda: len(_texts(page, "#floor-zones .zone-label")) == len(ZONES),
        "the zones on the floor plan",
        poll_s=0.1,
    )
    labels = page.evaluate(
        "[...document.querySelectorAll('#floor-zones g[data-zone]')]"
        ".map(g => [g.dataset.zone, g.querySelector('text').textContent])"
    )
    assert sorted(z for z, _ in labels) == sorted(ZONES)
    assert all(text.startswith(zone) for zone, text in labels), labels
    assert sorted(_texts(page, "#floor-cameras .camera-label")) == sorted(CAMERAS)
    feed = _texts(page, "#feed li .what")
    for name in [*ZONES, *CAMERAS, RULE, "odd"]:
        assert any(name in item for item in feed), (name, feed)
    assert any(ODD_TYPE in item for item in feed), feed
    assert sorted(_texts(page, "#cameras .camera-name")) == sorted(CAMERAS)
    for name in CAMERAS:
        js = f"document.querySelector('#cameras img[data-camera={_css(name)}]')?.naturalWidth > 0"
        wait_until(lambda js=js: page.evaluate(js), f"{name}'s picture", timeout_s=90, poll_s=0.2)
    page.screenshot(path=str(_shots() / "hostile-live.png"))
    _clean(page, "live")

    # 3D: plotly's legend (zones) and labels (cameras) as text
    page.click('[data-tab="view3d"]')
    page.wait_for_selector("#view3d .main-svg", timeout=60_000)
    wanted = sorted(
        f"{z} (alarm)" if i % 2 == 0 else f"{z} (occupied)" for i, z in enumerate(ZONES)
    )

    def legend() -> list[str]:
        return sorted(t for t in _texts(page, "#view3d .legendtext") if t.endswith(")"))

    wait_until(lambda: legend() == wanted, f"the zones {wanted} in the 3D legend", poll_s=0.2)
    wait_until(
        lambda: sorted(_texts(page, "#view3d .annotation-text")) == sorted(CAMERAS),
        "the cameras' labels in the 3D view",
        poll_s=0.2,
    )
    page.screenshot(path=str(_shots() / "hostile-view3d.png"))
    _clean(page, "3D")

    # history: the table's cells, each row's title, the zone filter's options
    page.click('[data-tab="history"]')
    wait_until(
        lambda: len(_texts(page, "#h-rows tr")) == len(_events()), "the history rows", poll_s=0.2
    )
    zones = _texts(page, "#h-rows tr td:nth-child(4)")
    cameras = _texts(page, "#h-rows tr td:nth-child(6)")
    assert set(ZONES) <= set(zones) and set(CAMERAS) <= set(cameras)
    assert ODD_TYPE in _texts(page, "#h-rows tr td:nth-child(3)")
    titles = page.evaluate("[...document.querySelectorAll('#h-rows tr')].map(r => r.title)")
    assert any(RULE in t for t in titles)
    assert sorted(_texts(page, "#h-zone option")) == sorted([*ZONES, "any"])
    # a filter by a hostile zone finds its rows, through an escaped query string
    page.select_option("#h-zone", ZONES[3])
    page.click("#h-search")
    wait_until(
        lambda: set(_texts(page, "#h-rows tr td:nth-child(4)")) == {ZONES[3]},
        "only the filtered zone's rows",
        poll_s=0.2,
    )
    page.screenshot(path=str(_shots() / "hostile-history.png"))
    _clean(page, "history")

    # back to live: the pictures still load (the tab's refresh restarts)
    page.click('[data-tab="live"]')
    _clean(page, "live again")


def _css(name: str) -> str:
    """A CSS attribute value in double quotes."""
    return '"' + name.replace("\\", "\\\\").replace('"', '\\"') + '"'


def _shots() -> Path:
    SHOTS.mkdir(parents=True, exist_ok=True)
    return SHOTS
