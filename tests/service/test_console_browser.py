"""The operator console in the real browser (Playwright + Debian's chromium) on `stereopose
serve` running the real demo as four live HTTP cameras (ffmpeg, looped): each its full stream
(stream copy) and a quarter-size detection substream, as a site's cameras would be set up.

One served demo is shared by the module. A viewer sees no acknowledge button and is refused
(403) when forcing one; an operator sees the demo's people move on the floor plan, an
energized-zone alarm in the feed within a second of its row in SQLite, acknowledges it and
finds the acknowledgement in SQLite, sees one acknowledged elsewhere arrive over the live
channel, each camera's picture, the 3D view, the history with its CSV export and an alarm's
clips; a camera killed shows as DOWN within a few seconds. Every page: no console error, no
request leaving 127.0.0.1, under the page's own Content-Security-Policy (so the tests wait by
polling page.evaluate: Playwright's wait_for_function evaluates strings in the page, which the
policy forbids). Screenshots go to out/console-screenshots/ (STEREOPOSE_SCREENSHOTS to put
them elsewhere)."""

from __future__ import annotations

import contextlib
import csv
import io
import json
import os
import shutil
import signal
import sqlite3
import subprocess
import sys
import time
import urllib.error
import urllib.request
from dataclasses import dataclass, field
from pathlib import Path
from urllib.parse import urlsplit

import pytest

from stereopose.io.pose2sim_data import pose2sim_demo_dir
from stereopose.pipeline.demo import CAMERAS, write_serve_demo_config
from streams import ffmpeg, free_port, serve, stop, wait_serving
from waiting import http_get, wait_until

pytestmark = [pytest.mark.realdata, pytest.mark.slow]

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
ARGS = ["--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run", "--disable-sync",
        "--disable-background-networking", "--disable-component-update",
        "--autoplay-policy=no-user-gesture-required"]  # fmt: skip
ROOT = Path(__file__).resolve().parents[2]
SHOTS = Path(os.environ.get("STEREOPOSE_SCREENSHOTS", ROOT / "out" / "console-screenshots"))
VIEWPORT = {"width": 1600, "height": 1000}
USERS = {"olga": ("operator", "olga's long passphrase"), "victor": ("viewer", "victor sees all")}
KILLED = CAMERAS[-1]
PLAYER = "document.getElementById('player')"


@dataclass
class Served:
    base: str
    data: Path
    log: Path
    proc: subprocess.Popen
    streams: dict[str, subprocess.Popen] = field(default_factory=dict)

    @property
    def db(self) -> Path:
        return self.data / "events.sqlite"

    def rows(self, sql: str, args: tuple = ()) -> list[tuple]:
        """Rows of the event log, read as another process would (read-only, no lock held)."""
        if not self.db.exists():
            return []
        try:
            with contextlib.closing(sqlite3.connect(f"file:{self.db}?mode=ro", uri=True)) as db:
                return db.execute(sql, args).fetchall()
        except sqlite3.OperationalError:  # not yet made, or its table not yet
            return []


def _cameras_up(base: str) -> bool:
    status, body = http_get(base + "/api/health")
    if status not in (200, 503):
        return False
    cams = json.loads(body).get("cameras", {})
    return set(cams) == set(CAMERAS) and all(c["state"] == "up" for c in cams.values())


def _post(url: str, body: dict | None, token: str | None = None) -> dict:
    headers = {"Content-Type": "application/json"}
    if token:
        headers["Authorization"] = f"Bearer {token}"
    data = json.dumps(body or {}).encode()
    request = urllib.request.Request(url, data=data, headers=headers, method="POST")
    with urllib.request.urlopen(request, timeout=60) as r:
        return json.loads(r.read())


def _add_user(config: Path, name: str, role: str, password: str) -> None:
    cmd = [sys.executable, "-m", "stereopose.cli", "users", "add", name, "--role", role,
           "--config", str(config)]  # fmt: skip
    done = subprocess.run(cmd, input=password + "\n", capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stdout + done.stderr


def _substream(video: Path, out: Path) -> Path:
    """`video` at a quarter of its size (272x480), H.264: the camera's detection substream."""
    cmd = [ffmpeg(), "-loglevel", "error", "-y", "-i", str(video), "-an", "-vf",
           "scale=272:480", "-c:v", "libx264", "-preset", "veryfast", "-g", "30", "-pix_fmt",
           "yuv420p", str(out)]  # fmt: skip
    subprocess.run(cmd, check=True, timeout=120)
    return out


@pytest.fixture(scope="module")
def served(tmp_path_factory) -> Served:
    """`stereopose serve` on the demo's four cameras served live over HTTP, each its full
    stream (copied, never decoded by the service: clips copy it) and a detection substream;
    two users."""
    tmp = tmp_path_factory.mktemp("console")
    videos = pose2sim_demo_dir() / "Demo_MultiPerson" / "videos"
    sources = {}
    for n in CAMERAS:
        sources[n] = videos / f"{n}.mp4"
        sources[n + "_sub"] = _substream(videos / f"{n}.mp4", tmp / f"{n}_sub.mp4")
    ports = {name: free_port() for name in sources}
    streams = {n: serve(v, ports[n], n, codec="copy") for n, v in sources.items()}
    wait_serving(list(streams.values()), list(ports.values()))
    port = free_port()
    config = write_serve_demo_config(tmp / "demo", tmp / "data", port, imgsz=320, detect_fps=10)
    lines = []
    for line in config.read_text().splitlines():
        if line.startswith("source = "):
            name = lines[-1].split('"')[1]
            lines.append(f'source = "http://127.0.0.1:{ports[name]}/{name}.ts"')
            line = f'detect = "http://127.0.0.1:{ports[name + "_sub"]}/{name}_sub.ts"'
        if line != "loop = true":  # live cameras are not looped by the service
            lines.append(line)
    text = "\n".join(lines) + "\n"
    text = text.replace("[serve]\n", "[storage]\nclip_pre_s = 1\nclip_post_s = 1\n\n"
                        "[serve]\ncamera_timeout_s = 3\nstatus_interval_s = 1\n", 1)  # fmt: skip
    config.write_text(text)
    for name, (role, password) in USERS.items():
        _add_user(config, name, role, password)
    log = tmp / "serve.log"
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    with open(log, "ab") as f:
        proc = subprocess.Popen([sys.executable, "-m", "stereopose.cli", "serve", str(config)],
                                stdout=f, stderr=subprocess.STDOUT, env=env)  # fmt: skip
    s = Served(f"http://127.0.0.1:{port}", tmp / "data", log, proc, streams)
    try:
        wait_until(lambda: proc.poll() is not None or _cameras_up(s.base), "the cameras up",
                   timeout_s=120, poll_s=0.25)  # fmt: skip
        assert proc.poll() is None, log.read_text()
        yield s
    finally:
        proc.send_signal(signal.SIGTERM)
        try:
            rc = proc.wait(timeout=40)
        except subprocess.TimeoutExpired:
            proc.kill()
            rc = None
        stop(list(s.streams.values()))
    assert rc == 0, log.read_text()[-4000:]


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


class Watched:
    """A logged-in page, with every console error, page error and request URL it made."""

    def __init__(self, browser, served: Served, user: str) -> None:
        self.user = user
        self.context = browser.new_context(viewport=VIEWPORT)
        self.page = self.context.new_page()
        self.problems: list[str] = []
        self.requests: list[str] = []
        self.page.on("console", lambda m: self.problems.append(f"{m.text} ({m.location['url']})")
                     if m.type == "error" else None)  # fmt: skip
        self.page.on("pageerror", lambda e: self.problems.append(f"page error: {e}"))
        self.page.on("request", lambda r: self.requests.append(r.url))
        self.page.goto(served.base + "/")
        self.page.wait_for_selector("#login-form", state="visible", timeout=20_000)
        self.page.fill("#login-user", user)
        self.page.fill("#login-password", USERS[user][1])
        self.page.click("#login-submit")
        self.page.wait_for_selector("#console", state="visible", timeout=60_000)  # argon2, loaded
        assert self.page.inner_text("#user") == f"{user} ({USERS[user][0]})"

    def people(self) -> dict[str, tuple[float, float]]:
        return {k: tuple(v) for k, v in self.page.evaluate(
            "Object.fromEntries([...document.querySelectorAll('#floor-people [data-person]"
            ":not(.lost)')].map(g => [g.dataset.person, [+g.dataset.x, +g.dataset.y]]))"
        ).items()}  # fmt: skip

    def close(self) -> None:
        self.context.close()
        assert self.problems == []
        outside = [u for u in self.requests if urlsplit(u).hostname != "127.0.0.1"]
        assert self.requests and outside == []


@pytest.fixture
def watched(browser, served):
    pages: list[Watched] = []

    def open_as(user: str) -> Watched:
        pages.append(Watched(browser, served, user))
        return pages[-1]

    yield open_as
    for w in pages:
        with contextlib.suppress(Exception):  # the last view, to see what a failure saw
            SHOTS.mkdir(parents=True, exist_ok=True)
            w.page.screenshot(path=str(SHOTS / f"last-{w.user}.png"))
        w.close()


def _alarm_rows(served: Served, after_id: int) -> list[tuple]:
    return served.rows("SELECT id, zone, type FROM events WHERE id > ? AND kind = 'energized' AND "
                       "type IN ('enter', 'approach') ORDER BY id", (after_id,))  # fmt: skip


def _last_id(served: Served) -> int:
    rows = served.rows("SELECT max(id) FROM events")
    return (rows[0][0] or 0) if rows else 0


def test_a_viewer_sees_no_ack_button_and_is_refused_when_forcing_one(watched, served):
    w = watched("victor")
    page = w.page
    page.wait_for_selector("#feed li.level-alarm", timeout=90_000)
    assert page.locator(".ack-button:visible").count() == 0
    assert page.locator("#feed .ack-button").count() == 0 and page.is_hidden("#alarm-ack")
    event_id = page.get_attribute("#feed li.level-alarm", "data-event-id")
    csrf = next(c["value"] for c in w.context.cookies() if c["name"] == "stereopose_csrf")
    forced = page.request.post(f"{served.base}/api/events/{event_id}/ack",
                               headers={"X-CSRF-Token": csrf})  # fmt: skip
    assert forced.status == 403
    assert served.rows("SELECT by FROM acks WHERE event = ?", (int(event_id),)) == []
    page.click("#logout")
    page.wait_for_selector("#login-form", state="visible")
    after = page.request.get(f"{served.base}/api/events")
    assert after.status == 401


def test_an_operator_sees_people_alarms_cameras_3d_and_history(watched, served):
    SHOTS.mkdir(parents=True, exist_ok=True)
    w = watched("olga")
    page = w.page
    # the demo's people on the floor plan, and their markers moving
    wait_until(lambda: len(w.people()) >= 2, "two people on the floor plan", timeout_s=120)
    first = w.people()

    def moved() -> bool:
        now = w.people()
        return any(abs(now[k][0] - first[k][0]) + abs(now[k][1] - first[k][1]) > 0.05
                   for k in now.keys() & first.keys())  # fmt: skip

    wait_until(moved, "a person's marker to move", timeout_s=30, poll_s=0.1)
    # an energized-zone alarm in the feed within a second of its row in SQLite
    start = _last_id(served)
    wait_until(lambda: _alarm_rows(served, start), "an energized-zone alarm in SQLite",
               timeout_s=90, poll_s=0.02)  # fmt: skip
    seen_row = time.monotonic()
    alarm_id, zone, kind = _alarm_rows(served, start)[0]
    item = f'#feed li[data-event-id="{alarm_id}"]'
    left_ms = max(0.0, seen_row + 1.0 - time.monotonic()) * 1000
    page.wait_for_selector(item, state="attached", timeout=left_ms)
    latency_s = time.monotonic() - seen_row
    print(f"alarm {alarm_id} in the feed {latency_s:.3f} s after its row was seen in SQLite")
    assert page.get_attribute(item, "data-zone") == zone
    assert "level-alarm" in page.get_attribute(item, "class")
    assert page.is_visible("#alarm-banner") and int(page.inner_text("#alarm-count")) >= 1
    assert page.get_attribute("body", "data-sound") == "sounding"
    assert page.locator(f'#floor-zones [data-zone="{zone}"]').count() == 1
    page.screenshot(path=str(SHOTS / "live-alarm.png"))
    # acknowledged from the feed: who and when in SQLite, and on the page
    page.click(f"{item} .ack-button")
    page.wait_for_selector(f"{item}.acked", timeout=10_000)
    assert "olga" in page.inner_text(f"{item} .ack-state")
    acked = "SELECT by, at FROM acks WHERE event = ?"
    wait_until(lambda: served.rows(acked, (alarm_id,)), "the acknowledgement in SQLite")
    ((by, at),) = served.rows(acked, (alarm_id,))
    assert by == "olga"
    assert abs(at - time.time()) < 60
    # an alarm acknowledged elsewhere (a script with a bearer token) is shown acknowledged
    other = page.get_attribute("#feed li.level-alarm:not(.acked)", "data-event-id")
    token = _post(served.base + "/api/login", {"username": "olga", "password": USERS["olga"][1]})
    _post(f"{served.base}/api/events/{other}/ack", None, token["token"])
    page.wait_for_selector(f'#feed li[data-event-id="{other}"].acked', timeout=10_000)
    # each camera's picture is an image
    for name in CAMERAS:
        js = f"document.querySelector('img[data-camera=\"{name}\"]')?.naturalWidth > 0"
        wait_until(lambda js=js: page.evaluate(js), f"{name}'s picture", poll_s=0.1)
    # the 3D view: skeletons, zones and cameras drawn by plotly
    page.click('[data-tab="view3d"]')
    page.wait_for_selector("#view3d .main-svg", timeout=60_000)
    skeletons = ("(document.getElementById('view3d').data || [])"
                 ".filter(t => t.name.startsWith('id ') && t.x.length > 0).length")  # fmt: skip
    wait_until(lambda: page.evaluate(skeletons) >= 1, "a skeleton in the 3D view", poll_s=0.1)
    names = page.evaluate("document.getElementById('view3d').data.map(t => t.name)")
    assert "cameras" in names and any(n.startswith(zone) for n in names)
    page.screenshot(path=str(SHOTS / "view3d.png"))
    # history: the acknowledged alarm found by its zone and type, its clip, the CSV export
    page.click('[data-tab="history"]')
    page.select_option("#h-zone", zone)
    page.select_option("#h-type", kind)
    page.click("#h-search")
    row = f'#h-rows tr[data-event-id="{alarm_id}"]'
    shown = ("[...document.querySelectorAll('#h-rows tr')]"
             ".map(r => [r.cells[3].textContent, r.dataset.type])")  # fmt: skip
    # the tab's own search (every event) may answer before the filtered one: its rows go then
    wait_until(lambda: {tuple(r) for r in page.evaluate(shown)} == {(zone, kind)},
               "only the filtered events in the history", timeout_s=20, poll_s=0.2)  # fmt: skip
    page.wait_for_selector(row, timeout=20_000)
    assert "olga" in page.inner_text(row)
    csv_url = page.get_attribute("#h-csv", "href")
    assert csv_url.startswith("/api/events.csv?") and f"zone={zone}" in csv_url
    answer = page.request.get(served.base + csv_url)
    assert answer.status == 200 and answer.headers["content-type"].startswith("text/csv")
    table = list(csv.DictReader(io.StringIO(answer.text())))
    assert table and {r["zone"] for r in table} == {zone}
    assert str(alarm_id) in {r["id"] for r in table}
    page.screenshot(path=str(SHOTS / "history.png"))


def _clipped(w: Watched, served: Served) -> dict | None:
    """The newest alarm with a clip, through the API as the page is logged in."""
    answer = w.page.request.get(f"{served.base}/api/events?limit=1000")
    assert answer.status == 200
    # both kinds: a camera's full-stream copy is finished just after its drawn clip
    both = (e for e in answer.json()["events"] if e["level"] == "alarm"
            and any(c.endswith(".full.mp4") for c in e["clips"])
            and any(not c.endswith(".full.mp4") for c in e["clips"]))  # fmt: skip
    return next(both, None)


def test_an_alarms_clips_play_in_the_page(watched, served):
    """Each clip of an alarm in the history plays in the page: the full stream's copy (H.264)
    in the video element, a drawn clip (MPEG-4 Part 2, which browsers do not decode) as the
    server's Motion JPEG in the picture beside it; each can be downloaded."""
    w = watched("olga")
    page = w.page
    wait_until(lambda: _clipped(w, served), "an alarm with a clip", timeout_s=90, poll_s=0.5)
    alarm = _clipped(w, served)
    page.click('[data-tab="history"]')  # the tab searches the newest events
    row = f'#h-rows tr[data-event-id="{alarm["id"]}"]'
    page.wait_for_selector(f"{row} button.play", timeout=20_000)
    frames = "document.getElementById('player-frames')"
    for url in alarm["clips"]:
        button = f'{row} button.play[data-clip="{url}"]'
        page.wait_for_selector(button, timeout=20_000)
        # clicked where it is now: a search answered late may have redrawn the table
        page.evaluate("(sel) => document.querySelector(sel).click()", button)
        assert page.get_attribute("#player-download", "href") == url
        if url.endswith(".full.mp4"):
            assert page.get_attribute("#player", "src") == url
            loaded = f"{PLAYER}.readyState >= 2 || !!{PLAYER}.error"
            wait_until(lambda js=loaded: page.evaluate(js), f"{url} loaded", poll_s=0.1)
            assert page.evaluate(f"{PLAYER}.error === null"), url
            assert page.evaluate(f"{PLAYER}.videoWidth") > 0
        else:
            assert page.get_attribute("#player-frames", "src").startswith(url + "/play?")
            shown = f"{frames}.complete || {frames}.naturalWidth > 0"
            wait_until(lambda js=shown: page.evaluate(js), f"{url} playing", poll_s=0.1)
            assert page.evaluate(f"{frames}.naturalWidth") > 0, url
            assert page.is_hidden("#player-error")
    full = [u for u in alarm["clips"] if u.endswith(".full.mp4")]
    assert full and len(full) < len(alarm["clips"])  # both kinds were played


def test_a_camera_killed_shows_as_down_within_seconds(watched, served):
    w = watched("olga")
    page = w.page
    card = f'figure.camera-card[data-camera="{KILLED}"]'
    page.wait_for_selector(f'{card}[data-state="up"]', timeout=20_000)
    start = _last_id(served)
    stop([served.streams.pop(KILLED), served.streams.pop(KILLED + "_sub")])
    killed = time.monotonic()

    shown = """(name) => {
        const card = document.querySelector(`figure.camera-card[data-camera="${name}"]`);
        const plan = document.querySelector(`#floor-cameras .camera[data-camera="${name}"]`);
        return card.classList.contains("down") && plan.classList.contains("down")
            && card.querySelector(".badge").textContent === "DOWN";
    }"""

    def shown_down() -> bool:
        return page.evaluate(shown, KILLED)

    wait_until(shown_down, f"{KILLED} shown down", timeout_s=15, poll_s=0.1)
    print(f"{KILLED} shown down {time.monotonic() - killed:.1f} s after its streams were killed")
    sql = "SELECT id FROM events WHERE type = 'camera_down' AND camera = ? AND id > ?"
    wait_until(lambda: served.rows(sql, (KILLED, start)), "camera_down in SQLite", timeout_s=20)
    down = served.rows(sql, (KILLED, start))
    page.wait_for_selector(f'#feed li[data-event-id="{down[0][0]}"]', timeout=5_000)
    assert shown_down()  # and it stays down
    page.locator(card).screenshot(path=str(SHOTS / "camera-down.png"))
