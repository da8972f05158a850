"""The service's HTTP app on a real uvicorn server: health, metrics, the offline OpenAPI page
and hostile requests, with a ServiceState fed as the frame loop will feed it."""

from __future__ import annotations

import json
import os
import re
import shutil
import socket
import threading
from html.parser import HTMLParser

import pytest
from prometheus_client.parser import text_string_to_metric_families

from served import Clock, event, frame_result, get, get_json, serving
from stereopose.site.health.state import ServiceState
from stereopose.site.http.app import create_app
from stereopose.web.limits import MAX_BODY_BYTES
from stereopose.web.server import MAX_HEADER_BYTES, Server, ServeSettings


@pytest.fixture
def fed() -> tuple[ServiceState, Clock]:
    """Two cameras at 10 fps for a second, two frames through the loop, three events, an
    MQTT queue of 4 and 1234 bytes of clips."""
    clock = Clock()
    state = ServiceState(["cam_01", "cam_02"], camera_timeout_s=2.0, clock=clock)
    for _ in range(11):
        state.camera_frame("cam_01", clock.now)
        state.camera_frame("cam_02", clock.now)
        clock.now += 0.1
    clock.now -= 0.1
    state.camera_dropped("cam_02", 2)
    state.camera_reconnect("cam_02")
    state.camera_frame("cam_02", clock.now)
    state.on_frame(frame_result(1, 2), {"detect": 0.02, "3d": 0.003})
    state.on_frame(frame_result(2, 3), {"detect": 0.03, "3d": 0.004}, t_arrival=clock.now - 0.5)
    state.on_events([event("enter"), event("exit")])
    state.on_event(event("enter"))
    state.register_queue("mqtt", lambda: 4, lambda: 0)
    state.register_storage(lambda: {"clips": 1234, "events_db": 56})
    return state, clock


def metrics_of(url: str) -> dict[str, dict[tuple, float]]:
    """/metrics parsed: sample name -> {label items: value}."""
    status, headers, body = get(url + "/metrics")
    assert status == 200 and headers["content-type"].startswith("text/plain")
    samples: dict[str, dict[tuple, float]] = {}
    for family in text_string_to_metric_families(body.decode()):
        for s in family.samples:
            samples.setdefault(s.name, {})[tuple(sorted(s.labels.items()))] = s.value
    return samples


def test_health_reports_the_state(fed):
    state, _ = fed
    with serving(state) as server:
        status, h = get_json(server.url + "/api/health")
    assert status == 200
    assert h["status"] == "ok" and h["problems"] == []
    assert h["version"] is None  # anonymous: no version (see test_app_exposure)
    assert h["uptime_s"] == pytest.approx(1.0) and h["outputs"] == {}
    assert (h["frames"], h["people"]) == (2, 3)
    cam1, cam2 = h["cameras"]["cam_01"], h["cameras"]["cam_02"]
    assert cam1 == {
        "fps": pytest.approx(10.0),
        "last_frame_age_s": 0.0,
        "state": "up",
        "frames": 11,
        "reconnects": 0,
        "dropped_frames": 0,
    }
    assert (cam2["frames"], cam2["reconnects"], cam2["dropped_frames"]) == (12, 1, 2)
    assert h["queues"] == {"mqtt": 4}
    assert h["storage"] == {"clips": 1234, "events_db": 56}


def test_a_camera_past_its_timeout_is_down_and_health_degraded(fed):
    state, clock = fed
    with serving(state) as server:
        clock.now += 2.5
        state.camera_frame("cam_01", clock.now)
        status, h = get_json(server.url + "/api/health")
        assert status == 200 and h["status"] == "degraded"
        cam2 = h["cameras"]["cam_02"]
        assert cam2["state"] == "down" and cam2["fps"] == 0.0
        assert cam2["last_frame_age_s"] == pytest.approx(2.5)
        assert h["problems"] == ["camera cam_02 down"]
        assert metrics_of(server.url)["stereopose_camera_up"] == {
            (("camera", "cam_01"),): 1.0,
            (("camera", "cam_02"),): 0.0,
        }
        clock.now += 2.5  # now neither delivers: down, and a plain HTTP probe sees it
        status, h = get_json(server.url + "/api/health")
        assert status == 503 and h["status"] == "down"
        assert h["problems"] == ["camera cam_01 down", "camera cam_02 down"]


def test_health_of_a_service_without_cameras_is_down():
    with serving(ServiceState()) as server:
        status, h = get_json(server.url + "/api/health")
    assert status == 503 and h["status"] == "down" and h["problems"] == ["no camera delivering"]


def test_metrics_names_and_values(fed):
    state, _ = fed
    with serving(state) as server:
        m = metrics_of(server.url)
    assert m["stereopose_frames_total"] == {(): 2.0}
    assert m["stereopose_frames_dropped_total"] == {
        (("camera", "cam_01"),): 0.0,
        (("camera", "cam_02"),): 2.0,
    }
    assert m["stereopose_camera_reconnects_total"][(("camera", "cam_02"),)] == 1.0
    assert m["stereopose_camera_fps"][(("camera", "cam_01"),)] == pytest.approx(10.0)
    assert m["stereopose_people"] == {(): 3.0}
    assert m["stereopose_events_total"] == {(("type", "enter"),): 2.0, (("type", "exit"),): 1.0}
    assert m["stereopose_queue_size"] == {(("queue", "mqtt"),): 4.0}
    assert m["stereopose_queue_dropped_total"] == {(("queue", "mqtt"),): 0.0}
    assert m["stereopose_storage_bytes"] == {
        (("kind", "clips"),): 1234.0,
        (("kind", "events_db"),): 56.0,
    }
    assert m["stereopose_info"] == {(("version", ""),): 1.0}  # anonymous: no version
    assert m["stereopose_uptime_seconds"][()] == pytest.approx(1.0)
    detect = (("stage", "detect"),)
    assert m["stereopose_stage_seconds_count"][detect] == 2.0
    assert m["stereopose_stage_seconds_sum"][detect] == pytest.approx(0.05)
    buckets = m["stereopose_stage_seconds_bucket"]
    assert buckets[(("le", "0.025"), ("stage", "detect"))] == 1.0
    assert buckets[(("le", "+Inf"), ("stage", "detect"))] == 2.0
    assert m["stereopose_end_to_end_latency_seconds_count"] == {(): 2.0}
    assert m["stereopose_end_to_end_latency_seconds_sum"][()] == pytest.approx(0.523)


def test_queue_sizes_are_read_at_each_scrape(fed):
    state, _ = fed
    sizes = iter(range(100))
    state.register_queue("live", lambda: next(sizes))
    with serving(state) as server:
        first = metrics_of(server.url)["stereopose_queue_size"][(("queue", "live"),)]
        second = metrics_of(server.url)["stereopose_queue_size"][(("queue", "live"),)]
    assert (first, second) == (0.0, 1.0)


def test_two_apps_have_their_own_metrics():
    a, b = ServiceState(), ServiceState()
    a.on_frame(frame_result(1, 1), {})
    with serving(a) as sa, serving(b) as sb:
        assert metrics_of(sa.url)["stereopose_frames_total"] == {(): 1.0}
        assert metrics_of(sb.url)["stereopose_frames_total"] == {(): 0.0}


def test_unknown_paths_wrong_methods_and_errors_are_json_never_tracebacks():
    app = create_app(ServiceState())

    @app.get("/api/broken")
    def broken() -> None:
        raise RuntimeError("secret internals")

    server = Server(app, ServeSettings(port=0))
    with server:
        status, headers, body = get(server.url + "/no/such/page")
        assert (status, json.loads(body)) == (404, {"detail": "Not Found"})
        assert headers["content-type"] == "application/json"
        status, headers, body = get(server.url + "/api/health", method="DELETE")
        assert (status, json.loads(body)) == (405, {"detail": "Method Not Allowed"})
        assert headers["allow"] == "GET"
        status, headers, body = get(server.url + "/api/broken")
        assert (status, json.loads(body)) == (500, {"detail": "internal error"})
        assert b"secret" not in body and b"Traceback" not in body
        assert "server" not in headers  # no server banner
        assert headers["x-content-type-options"] == "nosniff"
        assert get(server.url + "/api/health")[0] == 503  # still serving


def raw(port: int, request: bytes, end: bool = True) -> bytes:
    """The server's answer to raw bytes on a fresh connection, until it closes it. end: say
    that nothing more comes (not for a request cut short: the server answers, and its close
    with our bytes still unread resets the connection)."""
    chunks = []
    with socket.create_connection(("127.0.0.1", port), timeout=10) as s:
        s.sendall(request)
        if end:
            s.shutdown(socket.SHUT_WR)
        try:
            while chunk := s.recv(65536):
                chunks.append(chunk)
        except ConnectionResetError:
            pass  # after its answer
    return b"".join(chunks)


def test_huge_headers_bodies_and_garbage_are_refused_and_the_server_goes_on():
    app = create_app(ServiceState())

    @app.post("/api/echo")
    async def echo(body: dict) -> dict:  # a route that reads its body
        return {"keys": len(body)}

    with Server(app, ServeSettings(port=0)) as server:
        port = server.port
        assert port is not None
        big_header = b"x-junk: " + b"a" * (2 * MAX_HEADER_BYTES)
        answer = raw(port, b"GET /api/health HTTP/1.1\r\nhost: x\r\n" + big_header, end=False)
        assert answer.startswith(b"HTTP/1.1 400")
        answer = raw(port, b"GET /api/health?" + b"q" * 2 * MAX_HEADER_BYTES, end=False)
        assert answer.startswith(b"HTTP/1.1 400")
        answer = raw(port, b"\x16\x03\x01\x00\xa5\x01\x00\x00\xa1\x03\x03" + os.urandom(64))
        assert answer.startswith(b"HTTP/1.1 400")  # a TLS hello on the plain port
        announced = b"content-length: %d\r\n" % (MAX_BODY_BYTES + 1)
        answer = raw(port, b"POST /api/echo HTTP/1.1\r\nhost: x\r\n" + announced + b"\r\n")
        assert answer.startswith(b"HTTP/1.1 413")
        status, _, body = get(
            server.url + "/api/echo", "POST", b'{"a": 1}', {"content-type": "application/json"}
        )
        assert (status, json.loads(body)) == (200, {"keys": 1})
        piece = b"%x\r\n%s\r\n" % (65536, b"a" * 65536)
        chunked = piece * (MAX_BODY_BYTES // 65536 + 2) + b"0\r\n\r\n"
        head = (
            b"POST /api/echo HTTP/1.1\r\nhost: x\r\ncontent-type: application/json\r\n"
            b"transfer-encoding: chunked\r\n\r\n"
        )
        answer = raw(port, head + chunked)
        assert answer.startswith(b"HTTP/1.1 413")
        assert get(server.url + "/api/health")[0] == 503  # still serving


class _Refs(HTMLParser):
    def __init__(self) -> None:
        super().__init__()
        self.refs: list[str] = []

    def handle_starttag(self, tag: str, attrs: list) -> None:
        self.refs += [v for k, v in attrs if k in ("src", "href") and v]


def test_the_openapi_page_needs_nothing_from_outside():
    with serving(ServiceState()) as server:
        status, headers, body = get(server.url + "/docs")
        assert status == 200 and headers["content-type"].startswith("text/html")
        page = body.decode()
        parser = _Refs()
        parser.feed(page)
        assert len(parser.refs) >= 2 and all(r.startswith("/docs/assets/") for r in parser.refs)
        for ref in parser.refs:
            assert get(server.url + ref)[0] == 200
        assert not re.search(r"https?://", page)  # no CDN, no validator badge
        status, spec = get_json(server.url + "/openapi.json")
        assert status == 200 and {"/api/health", "/metrics"} <= set(spec["paths"])


CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")


@pytest.mark.slow
def test_the_openapi_page_renders_in_chromium_from_this_server_alone():
    if CHROMIUM is None:
        if os.environ.get("STEREOPOSE_REQUIRE_BROWSER") == "1":
            pytest.fail("chromium not found; install Debian's chromium package")
        pytest.skip("chromium not installed (Debian package chromium)")
    from playwright.sync_api import sync_playwright

    with serving(ServiceState()) as server, sync_playwright() as p:
        args = ["--no-sandbox", "--disable-gpu", "--disable-background-networking"]
        browser = p.chromium.launch(executable_path=CHROMIUM, args=args)
        page = browser.new_page()
        problems: list[str] = []
        requests: list[str] = []
        page.on("console", lambda m: problems.append(m.text) if m.type == "error" else None)
        page.on("pageerror", lambda e: problems.append(str(e)))
        page.on("request", lambda r: requests.append(r.url))
        page.goto(server.url + "/docs")
        page.wait_for_selector('[data-path="/api/health"]', timeout=30_000)
        page.wait_for_selector('[data-path="/metrics"]', timeout=30_000)
        browser.close()
    assert problems == []
    assert requests and all(r.startswith(server.url + "/") for r in requests), requests


def test_readers_see_consistent_snapshots_while_the_loop_writes():
    state = ServiceState(["cam_01", "cam_02"])
    stop = threading.Event()
    errors: list[BaseException] = []

    def loop() -> None:  # as the frame loop: every frame times the same two stages
        i = 0
        try:
            while not stop.is_set():
                i += 1
                state.camera_frame("cam_01")
                state.camera_frame("cam_02")
                state.on_frame(frame_result(i, i % 4), {"detect": 0.001, "3d": 0.0005})
                state.on_events([event("enter")] * (i % 3))
                stop.wait(0.0005)  # a frame rate far above a camera's, leaving readers a turn
        except BaseException as e:
            errors.append(e)

    writer = threading.Thread(target=loop)
    with serving(state) as server:
        writer.start()
        try:
            last = 0.0
            for _ in range(15):
                m = metrics_of(server.url)
                frames = m["stereopose_frames_total"][()]
                assert frames >= last
                last = frames
                # one snapshot: each stage saw exactly the frames counted, no more, no less
                for stage in ("detect", "3d"):
                    assert m["stereopose_stage_seconds_count"][(("stage", stage),)] == frames
                assert m["stereopose_end_to_end_latency_seconds_count"][()] == frames
                status, h = get_json(server.url + "/api/health")
                assert status == 200 and h["frames"] >= frames
        finally:
            stop.set()
            writer.join(10)
    assert not writer.is_alive() and errors == []
    assert last > 0
