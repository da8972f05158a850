"""The console's data routes on a real server over a real event log (written by the SQLite
sink) and the real demo's rig and site: events filtered, newest first, as CSV; an
acknowledgement stored in SQLite and pushed; clips served with Range and nothing else
(each traversal variant); people, zones, cameras and snapshots from frames given to the
live hub; the live channel delivering a new event within a deadline of its row."""

from __future__ import annotations

import contextlib
import http.client
import json
import sqlite3
import threading
from datetime import UTC, datetime
from urllib.parse import urlsplit

import cv2
import httpx
import numpy as np
import pytest

from consoled import WALL_START, console_server, demo_plan, zone_event
from stereopose.io.sinks.base import FrameResult
from stereopose.io.sinks.clips import clip_name
from stereopose.types import Event, People3D
from waiting import wait_until

pytestmark = pytest.mark.realdata  # the real demo's calibration and site

# a real person of the demo (served, frame 3): joints in metres, COCO order
REAL_JOINTS = [
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


@pytest.fixture(scope="module")
def plan(tmp_path_factory):
    return demo_plan(tmp_path_factory.mktemp("plan"))


@pytest.fixture
def served(tmp_path, plan):
    with console_server(tmp_path / "out", plan) as s:
        yield s


def _rows(served, sql: str, args=()) -> list[tuple]:
    db = sqlite3.connect(served.out / "events.sqlite")
    try:
        return db.execute(sql, args).fetchall()
    finally:
        db.close()


def _log(served) -> list[Event]:
    events = [
        zone_event(30, "enter"),
        zone_event(60, "enter", 8, "work_area", "work_area"),
        zone_event(90, "dwell", 8, "work_area", "work_area"),
        Event(
            t=4.0,
            frame=120,
            person=-1,
            zone="",
            kind="camera",
            type="camera_down",
            onset_t=4.0,
            camera="cam02",
        ),
        zone_event(150, "exit"),
    ]
    for e in events:
        served.db.write_events([e])
    assert served.db.committed == len(events)
    return events


def test_events_newest_first_with_wall_time_level_and_filters(served):
    _log(served)
    c = served.client("vera")
    try:
        events = c.get("/api/events").json()["events"]
        assert [e["id"] for e in events] == [5, 4, 3, 2, 1]
        assert [e["level"] for e in events] == ["info", "alarm", "warning", "info", "alarm"]
        first = events[-1]
        assert first["wall_t"] == pytest.approx(WALL_START + 1.0)
        assert (first["person"], first["zone"], first["type"], first["ack"]) == (
            7,
            "overhead_busbar",
            "enter",
            None,
        )
        assert events[1]["camera"] == "cam02" and events[1]["type"] == "camera_down"

        def ids(**params) -> list[int]:
            r = c.get("/api/events", params=params)
            assert r.status_code == 200, r.text
            return [e["id"] for e in r.json()["events"]]

        assert ids(person=8) == [3, 2]
        assert ids(zone="overhead_busbar") == [5, 1]
        assert ids(type="camera_down") == [4]
        assert ids(since=WALL_START + 2.5) == [5, 4, 3]
        assert ids(until=WALL_START + 2.5) == [2, 1]
        iso = datetime.fromtimestamp(WALL_START + 2.5, UTC).isoformat()
        assert ids(since=iso) == [5, 4, 3]
        assert ids(since=iso.replace("+00:00", "Z"), type="enter") == []
        assert ids(limit=2) == [5, 4]
        assert ids(limit=2, before_id=4) == [3, 2]
        assert ids(after_id=3) == [5, 4]
        for bad in (
            {"since": "yesterday"},
            {"limit": 0},
            {"limit": 5000},
            {"person": "x"},
            {"before_id": -1},
        ):
            r = c.get("/api/events", params=bad)
            assert r.status_code == 422, bad
            assert r.json()["detail"]
    finally:
        c.close()


def test_events_as_csv_with_the_same_filters(served):
    _log(served)
    served.db.write_events([zone_event(160, "enter", 9, "=HYPERLINK(1)", "restricted")])
    c = served.client("vera")
    try:
        r = c.get("/api/events.csv", params={"type": "enter"})
        assert r.status_code == 200
        assert r.headers["content-type"].startswith("text/csv")
        assert r.headers["content-disposition"].startswith("attachment; filename=")
        lines = r.text.splitlines()
        assert lines[0].startswith("id,time,wall_t,t,frame,person,zone,kind,type,level")
        rows = [line.split(",") for line in lines[1:]]
        assert [row[0] for row in rows] == ["6", "2", "1"]
        assert rows[0][6] == "'=HYPERLINK(1)"  # never a formula in a spreadsheet
        assert rows[0][9] == "warning"  # entering a restricted zone
    finally:
        c.close()


def test_an_ack_is_recorded_in_sqlite_once_and_pushed(served):
    _log(served)
    otto, ada, vera = (served.client(u) for u in ("otto", "ada", "vera"))
    try:
        assert vera.post("/api/events/1/ack").status_code == 403
        assert not _rows(served, "SELECT * FROM acks")  # refused: nothing written
        r = otto.post("/api/events/1/ack")
        assert r.status_code == 200
        body = r.json()
        assert body["id"] == 1 and body["ack"]["by"] == "otto"
        assert _rows(served, "SELECT event, by, at FROM acks") == [(1, "otto", body["ack"]["at"])]
        again = ada.post("/api/events/1/ack")  # idempotent: the first one stays
        assert again.status_code == 200 and again.json() == body
        assert otto.post("/api/events/99/ack").status_code == 404
        assert _rows(served, "SELECT COUNT(*) FROM acks") == [(1,)]
        listed = {e["id"]: e["ack"] for e in vera.get("/api/events").json()["events"]}
        assert listed[1] == body["ack"] and listed[2] is None
    finally:
        for c in (otto, ada, vera):
            c.close()


def _write_clip(path, frames: int = 5) -> None:
    w = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), 10, (64, 48))
    for i in range(frames):
        w.write(np.full((48, 64, 3), 40 * i, np.uint8))
    w.release()


def _raw(url: str, path: str, headers: dict) -> int:
    """The status of GET `path` sent exactly as written (no client normalising it)."""
    u = urlsplit(url)
    conn = http.client.HTTPConnection(u.hostname, u.port, timeout=10)
    try:
        conn.request("GET", path, headers=headers)
        return conn.getresponse().status
    finally:
        conn.close()


def test_clips_are_listed_served_with_range_and_nothing_else(served, tmp_path):
    _log(served)
    clips = served.out / "clips"
    clips.mkdir()
    name = clip_name(WALL_START + 1.0, 7, "overhead_busbar", "cam01") + ".mp4"
    _write_clip(clips / name)
    (clips / "partial.part.mp4").write_bytes(b"x" * 100)
    (clips / ".hidden.mp4").write_bytes(b"x" * 100)
    outside = tmp_path / "secret.mp4"
    outside.write_bytes(b"secret" * 100)
    (clips / "link.mp4").symlink_to(outside)
    (clips / "sub").mkdir()
    _write_clip(clips / "sub" / "a.mp4")
    c = served.client("vera")
    try:
        events = {e["id"]: e for e in c.get("/api/events").json()["events"]}
        assert events[1]["clips"] == [f"/api/clips/{name}"]
        assert events[2]["clips"] == [] and events[4]["clips"] == []
        r = c.get(f"/api/clips/{name}")
        assert r.status_code == 200 and r.headers["content-type"] == "video/mp4"
        assert r.content == (clips / name).read_bytes()
        part = c.get(f"/api/clips/{name}", headers={"Range": "bytes=0-99"})
        assert part.status_code == 206 and len(part.content) == 100
        assert part.headers["content-range"].startswith("bytes 0-99/")
        token = c.cookies["stereopose_session"]
    finally:
        c.close()
    auth = {"Authorization": f"Bearer {token}"}
    assert _raw(served.url, f"/api/clips/{name}", auth) == 200
    for path in (
        "/api/clips/../events.sqlite",
        "/api/clips/..%2Fevents.sqlite",
        "/api/clips/%2e%2e%2fevents.sqlite",
        "/api/clips/%2E%2E/users.json",
        "/api/clips/..%2f..%2f..%2fetc%2fpasswd",
        "/api/clips/%2Fetc%2Fpasswd",
        "/api/clips//etc/passwd",
        "/api/clips/sub/a.mp4",
        "/api/clips/sub%2Fa.mp4",
        "/api/clips/link.mp4",
        "/api/clips/.hidden.mp4",
        "/api/clips/partial.part.mp4",
        "/api/clips/..mp4",
        "/api/clips/events.sqlite",
        "/api/clips/users.json",
        "/api/clips/missing.mp4",
        "/api/clips/%00.mp4",
        "/api/clips/" + "a" * 300 + ".mp4",
    ):
        status = _raw(served.url, path, auth)
        assert 400 <= status < 500, (path, status)
    for path in (
        "/console/../users.json",
        "/console/%2e%2e/%2e%2e/web.py",
        "/console/..%2f..%2fweb.py",
        "/console/%2e%2e%2fauth.py",
        "/console//etc/passwd",
        "/console/../../../../etc/passwd",
        "/console/%2Fetc%2Fpasswd",
    ):
        status = _raw(served.url, path, {})
        assert 400 <= status < 500, (path, status)


def _frame(frame: int, shift: float, events=(), images=None) -> FrameResult:
    joints = np.asarray(REAL_JOINTS)[None] + [shift, 0.0, 0.0]
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


def test_people_zones_and_trails_from_the_frames(served):
    hub = served.console.hub
    c = served.client("vera")
    try:
        assert c.get("/api/people").json() == {
            "frame": None,
            "t": None,
            "wall_t": None,
            "people": [],
        }
        zones = {z["name"]: z for z in c.get("/api/zones").json()["zones"]}
        assert set(zones) == {"overhead_busbar", "work_area", "qs1_front", "qs1_handle"}
        assert zones["overhead_busbar"]["state"] == "free"
        assert zones["overhead_busbar"]["kind"] == "energized"
        assert len(zones["overhead_busbar"]["polygon"]) >= 3
        for i in range(20):
            events = [zone_event(i, "enter")] if i == 10 else []
            hub.on_frame(_frame(i, -0.05 * i, events), WALL_START)
        body = c.get("/api/people").json()
        assert body["frame"] == 19 and body["wall_t"] == pytest.approx(WALL_START + 19 / 30)
        (p,) = body["people"]
        assert p["id"] == 7 and len(p["joints"]) == 17 and p["zones"] == ["overhead_busbar"]
        assert p["position"][0] == pytest.approx(0.25 - 0.95, abs=0.02)  # mid-hip, moved
        assert -180 <= p["heading_deg"] <= 180
        xs = [x for x, _ in p["trail"]]
        assert 2 <= len(xs) <= 50 and xs == sorted(xs, reverse=True)  # walking to -x
        zones = {z["name"]: z for z in c.get("/api/zones").json()["zones"]}
        assert zones["overhead_busbar"]["state"] == "alarm"
        assert zones["overhead_busbar"]["occupants"] == [7]
        hub.on_frame(_frame(20, -1.0, [zone_event(20, "exit")]), WALL_START)
        zones = {z["name"]: z for z in c.get("/api/zones").json()["zones"]}
        assert zones["overhead_busbar"]["state"] == "free"
        assert zones["overhead_busbar"]["occupants"] == []
        assert all(z["enabled"] for z in zones.values())
        # switched off over MQTT: shown off; on again: as before
        off = zone_event(21, "zone_disabled", person=-1, kind="service")
        hub.on_frame(_frame(21, 0.0, [off]), WALL_START)
        zones = {z["name"]: z for z in c.get("/api/zones").json()["zones"]}
        assert zones["overhead_busbar"]["enabled"] is False
        assert zones["overhead_busbar"]["state"] == "off"
        on = zone_event(22, "zone_enabled", person=-1, kind="service")
        hub.on_frame(_frame(22, 0.0, [on]), WALL_START)
        zones = {z["name"]: z for z in c.get("/api/zones").json()["zones"]}
        assert zones["overhead_busbar"]["enabled"] is True
        assert zones["overhead_busbar"]["state"] == "free"
    finally:
        c.close()


def test_cameras_their_view_health_and_snapshots(served, plan):
    hub = served.console.hub
    c = served.client("vera")
    try:
        cams = c.get("/api/cameras").json()["cameras"]
        assert [cam["name"] for cam in cams] == list(plan.rig.names)
        for cam in cams:
            assert len(cam["position"]) == 3 and 10 < cam["hfov_deg"] < 120
            assert len(cam["floor_fov"]) >= 3 and cam["image_size"] == [1088, 1920]
            assert cam["snapshot"] == f"/api/cameras/{cam['name']}/snapshot.jpg"
            assert cam["health"]["state"] == "down" and cam["health"]["frames"] == 0
        assert c.get("/api/cameras/cam01/snapshot.jpg").status_code == 503
        assert c.get("/api/cameras/nope/snapshot.jpg").status_code == 404
        image = np.zeros((1920, 1088, 3), np.uint8)
        image[500:900, 300:700] = (0, 128, 255)
        hub.on_frame(_frame(1, 0.0, images={"cam01": image, "cam02": None}), WALL_START)
        wait_until(
            lambda: c.get("/api/cameras/cam01/snapshot.jpg").status_code == 200,
            "the first snapshot (its drawing compiled at first)",
            timeout_s=90,
        )
        r = c.get("/api/cameras/cam01/snapshot.jpg")
        assert (
            r.headers["content-type"] == "image/jpeg" and r.headers["cache-control"] == "no-store"
        )
        picture = cv2.imdecode(np.frombuffer(r.content, np.uint8), cv2.IMREAD_COLOR)
        assert picture.shape == (960, 544, 3)  # at the snapshot scale, 0.5
        assert c.get("/api/cameras/cam02/snapshot.jpg").status_code == 503
        served.state.camera_frame("cam01")
        health = {cam["name"]: cam["health"] for cam in c.get("/api/cameras").json()["cameras"]}
        assert health["cam01"]["state"] == "up" and health["cam02"]["state"] == "down"
        queues = httpx.get(served.url + "/api/health").json()["queues"]
        assert "console_snapshots" in queues and "console_clients" in queues
    finally:
        c.close()


def test_a_small_substreams_picture_keeps_its_size_so_ids_can_be_read():
    from stereopose.site.pictures import SNAPSHOT_MIN_SIDE, picture_scale

    assert picture_scale((1920, 1088, 3), 0.5) == 0.5  # 960 px: large enough at half size
    assert picture_scale((480, 272, 3), 0.5) == 1.0  # never above the frame's own size
    assert picture_scale((1000, 800, 3), 0.5) == pytest.approx(SNAPSHOT_MIN_SIDE / 1000)
    assert picture_scale((0, 0, 3), 0.25) == 1.0  # no division by zero


class _Stream:
    """The live channel read on a thread: every (event, data) pair kept in order."""

    def __init__(self, client: httpx.Client) -> None:
        self.messages: list[tuple[str, dict]] = []
        self.response = None
        self._taken: dict[str, int] = {}  # kind -> index after the last one taken
        self._client = client
        self._thread = threading.Thread(target=self._read, daemon=True)
        self._thread.start()

    def _read(self) -> None:
        with (
            contextlib.suppress(httpx.HTTPError),
            self._client.stream("GET", "/api/live", timeout=30) as r,
        ):
            self.response = r
            kind = None
            for line in r.iter_lines():
                if line.startswith("event: "):
                    kind = line[7:]
                elif line.startswith("data: ") and kind:
                    self.messages.append((kind, json.loads(line[6:])))
                    kind = None

    def next(self, kind: str, timeout_s: float, where=lambda body: True) -> dict:
        """The next message of `kind` (after the last one taken) that `where` accepts."""
        found: list[dict] = []

        def seen() -> bool:
            for i in range(self._taken.get(kind, 0), len(self.messages)):
                k, body = self.messages[i]
                if k == kind and where(body):
                    self._taken[kind] = i + 1
                    found.append(body)
                    return True
            return False

        wait_until(seen, f"a live {kind} message", timeout_s=timeout_s)
        return found[0]


def test_the_live_channel_pushes_state_events_and_acks(served):
    c, otto = served.client("vera"), served.client("otto")
    try:
        live = _Stream(c)
        assert live.next("cameras", 10)["cameras"][0]["name"] == "cam01"
        assert "zones" in live.next("zones", 10)
        live.next("people", 10)
        assert live.response.headers["content-type"].startswith("text/event-stream")
        served.db.write_events([zone_event(30, "enter")])  # committed when this returns
        item = live.next("event", 2.0)  # within 2 s of its row
        assert item["id"] == 1 and item["level"] == "alarm" and item["ack"] is None
        served.console.hub.on_frame(_frame(31, 0.0), WALL_START)
        assert live.next("people", 5, lambda b: b["frame"] == 31)["people"][0]["id"] == 7
        otto.post("/api/events/1/ack").raise_for_status()
        pushed = live.next("ack", 5)
        assert pushed["id"] == 1 and pushed["ack"]["by"] == "otto"
        assert served.console.hub.clients == 1
    finally:
        c.close()
        otto.close()
    wait_until(lambda: served.console.hub.clients == 0, "the stream closed", timeout_s=10)


def test_the_live_channel_is_bounded_in_clients(served):
    hub = served.console.hub
    hub.max_clients = 2
    clients = [served.client("vera") for _ in range(3)]
    try:
        streams = [_Stream(c) for c in clients[:2]]
        for s in streams:
            s.next("cameras", 10)
        assert clients[2].get("/api/live").status_code == 503
    finally:
        for c in clients:
            c.close()


def test_a_slow_subscriber_loses_its_oldest_messages_counted():
    import asyncio

    from stereopose.site.live import Subscriber

    loop = asyncio.new_event_loop()
    try:
        sub = Subscriber(loop, maxlen=3)
        for i in range(5):
            sub.put(f"m{i}".encode())
        assert sub.dropped == 2 and sub.take() == [b"m2", b"m3", b"m4"] and len(sub) == 0
    finally:
        loop.close()
    sub.put(b"after")  # its loop gone: kept, never an error
    assert sub.take() == [b"after"]


def test_trails_are_bounded_and_forgotten(served):
    hub = served.console.hub
    for i in range(400):  # 13 s at 30 fps, walking
        hub.on_frame(_frame(i, -0.003 * i), WALL_START)
    (p,) = hub.people()["people"]
    assert 40 <= len(p["trail"]) <= 50  # about the last 5 s, at most 50 points
    assert p["trail"][0][0] == pytest.approx(0.25 - 0.003 * 250, abs=0.05)
    nobody = People3D.empty(400, 4)
    for i in range(400, 560):
        hub.on_frame(FrameResult(i, i / 30.0, {}, nobody), WALL_START)
    assert hub.people()["people"] == [] and not hub.scene.trails()  # gone over 5 s: forgotten
    metrics = httpx.get(served.url + "/metrics").text
    assert 'stereopose_queue_size{queue="console_snapshots"}' in metrics
    assert 'stereopose_queue_dropped_total{queue="console_snapshots"}' in metrics


def test_people_carry_their_posture_when_the_behaviour_rules_give_one(served):
    from stereopose.behaviour import PostureTracker

    tracker = PostureTracker(30.0)
    hub = served.console.hub
    for i in range(5):
        f = _frame(i, 0.0)
        postures = tracker.update(f.t, f.people3d)
        hub.on_frame(FrameResult(f.frame, f.t, {}, f.people3d, (), None, postures), WALL_START)
    (p,) = hub.people()["people"]
    assert p["posture"] == postures[7].posture and p["posture"] != "lying"  # on their feet
    assert p["flags"] == list(postures[7].flags)


def test_behaviour_alarms_are_alarms_and_every_column_is_listed(served):
    down = Event(
        t=2.0,
        frame=60,
        person=7,
        zone="",
        kind="behaviour",
        type="person_down",
        onset_t=1.5,
        rule="down",
        posture="lying",
        height_m=0.2,
    )
    served.db.write_events([down])
    c = served.client("vera")
    try:
        (e,) = c.get("/api/events").json()["events"]
        assert e["level"] == "alarm" and e["type"] == "person_down"
        assert (e["rule"], e["posture"], e["height_m"]) == ("down", "lying", 0.2)
        assert e["clips"] == []
    finally:
        c.close()


def test_open_live_streams_end_when_the_service_stops(tmp_path, plan):
    with console_server(tmp_path / "out", plan) as s:
        c = s.client("vera")
        live = _Stream(c)
        live.next("cameras", 10)
        s.console.close()  # as serve does before stopping its server
        wait_until(lambda: not live._thread.is_alive(), "the stream's end", timeout_s=10)
        assert s.console.hub.clients == 0
        c.close()


def test_a_hand_inside_an_energized_zone_makes_its_person_an_occupant_at_once(served):
    """No enter event yet (its debounce): the wrist inside the busbar's prism is enough."""
    hub = served.console.hub
    busbar = next(z for z in hub.scene.zones_by_name.values() if z.name == "overhead_busbar")
    centre = [*np.asarray(busbar.polygon, float).mean(axis=0), sum(busbar.z) / 2]
    c = served.client("vera")
    try:
        frame = _frame(1, 0.0)
        frame.people3d.joints[0, 10] = centre  # the right wrist, inside the prism
        hub.on_frame(frame, WALL_START)
        zones = {z["name"]: z for z in c.get("/api/zones").json()["zones"]}
        assert zones["overhead_busbar"]["occupants"] == [7]
        assert zones["overhead_busbar"]["state"] == "alarm"
        (p,) = c.get("/api/people").json()["people"]
        assert "overhead_busbar" in p["zones"]
        hub.on_frame(_frame(2, 0.0), WALL_START)  # the hand out again
        zones = {z["name"]: z for z in c.get("/api/zones").json()["zones"]}
        assert zones["overhead_busbar"]["occupants"] == []
        assert c.get("/api/people").json()["people"][0]["zones"] == []
    finally:
        c.close()
