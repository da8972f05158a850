"""What an anonymous client learns from the service, on a real server: no version without a
session (health, metrics, the OpenAPI document), no answer for a Host that is not one of the
server's names (DNS rebinding), and no file path of the server in an error answer."""

from __future__ import annotations

import contextlib
import http.client
import json
import logging
import socket
from pathlib import Path

import httpx
import pytest
from prometheus_client.parser import text_string_to_metric_families

from consoled import console_server
from stereopose import __version__
from stereopose.errors import StereoposeError
from stereopose.site.health.state import ServiceState
from stereopose.site.http.app import create_app
from stereopose.web.hosts import allowed_hosts, default_hosts, host_of
from stereopose.web.server import Server, ServeSettings


def _info(text: str) -> dict:
    for family in text_string_to_metric_families(text):
        if family.name == "stereopose_info":
            return {s.labels["version"]: s.value for s in family.samples}
    raise AssertionError("no stereopose_info")


def test_the_version_is_shown_only_with_a_session(tmp_path: Path) -> None:
    with console_server(tmp_path / "data", events=False) as served:
        with served.client() as anon:
            assert anon.get("/api/health").json()["version"] is None
            assert _info(anon.get("/metrics").text) == {"": 1.0}
            spec = anon.get("/openapi.json").json()
            assert spec["info"]["version"] != __version__ and "/api/health" in spec["paths"]
            assert __version__ not in anon.get("/openapi.json").text
            assert anon.get("/docs").status_code == 200  # the page still loads its document
            # a token that names no session is anonymous too
            bad = {"Authorization": "Bearer not-a-session"}
            assert anon.get("/api/health", headers=bad).json()["version"] is None
        with contextlib.closing(served.client("vera")) as viewer:
            assert viewer.get("/api/health").json()["version"] == __version__
            assert _info(viewer.get("/metrics").text) == {__version__: 1.0}
            assert viewer.get("/openapi.json").json()["info"]["version"] == __version__
            token = viewer.cookies["stereopose_session"]
        with httpx.Client(base_url=served.url) as scraper:  # Prometheus with a bearer token
            metrics = scraper.get("/metrics", headers={"Authorization": f"Bearer {token}"})
            assert _info(metrics.text) == {__version__: 1.0}


def _get(port: int, *hosts: str, path: str = "/api/health") -> tuple[int, bytes]:
    """GET `path` with these Host headers (none: no Host), over a raw HTTP/1.1 connection."""
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=10)
    try:
        conn.putrequest("GET", path, skip_host=True)
        for host in hosts:
            conn.putheader("Host", host)
        conn.endheaders()
        resp = conn.getresponse()
        return resp.status, resp.read()
    finally:
        conn.close()


def test_a_foreign_host_is_refused_and_the_server_s_names_are_served() -> None:
    state = ServiceState()
    app = create_app(state, allowed_hosts=allowed_hosts("127.0.0.1", ["scada.example.org"]))
    with Server(app, ServeSettings(port=0)) as server:
        port = server.port
        for host in (
            "attacker.example.com",
            f"attacker.example.com:{port}",
            "127.0.0.2",
            "scada.example.org.evil",
            "localhost.attacker.example",
        ):
            status, body = _get(port, host)
            assert status == 421, host
            assert json.loads(body) == {"detail": "unknown host: not a name of this server"}
            assert _get(port, host, path="/metrics")[0] == 421
        # two Host headers: refused (by the HTTP parser itself, or here)
        assert _get(port, "127.0.0.1", "attacker.example.com")[0] in (400, 421)
        served = (
            f"127.0.0.1:{port}",
            "127.0.0.1",
            f"localhost:{port}",
            "LOCALHOST.",
            f"[::1]:{port}",
            "scada.example.org",
            f"Scada.Example.Org:{port}",
        )
        for host in served:
            assert _get(port, host)[0] == 503, host  # served: down, no camera yet
        status, body = _get(port, f"127.0.0.1:{port}", path="/metrics")
        assert status == 200 and b"stereopose_frames_total" in body


def test_the_default_names_follow_the_bound_address() -> None:
    assert default_hosts("127.0.0.1") == {"localhost", "127.0.0.1", "::1"}
    assert "10.1.2.3" in default_hosts("10.1.2.3")
    every = default_hosts("0.0.0.0")
    assert host_of(socket.gethostname()) in every and host_of(socket.getfqdn()) in every
    assert "127.0.0.1" in every and "attacker.example.com" not in every
    assert {"a.example.org", "localhost"} <= set(allowed_hosts("::", ["A.Example.Org."]))
    assert host_of("[fe80::1]:8787") == "fe80::1" and host_of("Name.Local.:80") == "name.local"


def test_wildcards_in_the_allowed_hosts() -> None:
    app = create_app(ServiceState(), allowed_hosts=("*.example.org",))
    with Server(app, ServeSettings(port=0)) as server:
        assert _get(server.port, "cam.example.org")[0] == 503
        assert _get(server.port, "example.org.evil")[0] == 421
    app = create_app(ServiceState(), allowed_hosts=("*",))
    with Server(app, ServeSettings(port=0)) as server:
        assert _get(server.port, "anything.example")[0] == 503


def test_error_answers_name_no_file_of_the_server(tmp_path: Path, caplog) -> None:
    data = tmp_path / "secret-folder"
    data.mkdir()
    (data / "events.sqlite").write_bytes(b"this is not a database" * 100)
    caplog.set_level(logging.WARNING)
    with console_server(data, events=False) as served:
        operator = served.client("otto")
        answers = [
            operator.get("/api/events"),
            operator.get("/api/events.csv"),
            operator.post("/api/events/1/ack"),
        ]
        operator.close()
    for r in answers:
        assert r.status_code == 503, r.text
        assert "secret-folder" not in r.text and str(tmp_path) not in r.text, r.text
        assert "/" not in r.json()["detail"]
    assert str(data / "events.sqlite") in caplog.text  # the log keeps the detail


def test_a_library_error_no_route_caught_is_a_503_without_its_message(caplog) -> None:
    app = create_app(ServiceState())

    @app.get("/api/fails")
    def fails() -> None:
        raise StereoposeError("/var/lib/stereopose/events.sqlite: disk I/O error")

    caplog.set_level(logging.ERROR)
    with Server(app, ServeSettings(port=0)) as server, httpx.Client() as c:
        r = c.get(server.url + "/api/fails")
    assert r.status_code == 503 and "/var/lib" not in r.text
    assert r.headers["x-content-type-options"] == "nosniff"
    assert "/var/lib/stereopose/events.sqlite: disk I/O error" in caplog.text


@pytest.mark.parametrize(
    "text, path",
    [
        ("/srv/data/events.sqlite: cannot read the event log: file is not a database", True),
        ("C:\\stereopose\\users.json: cannot read the users", True),
        ("'~/data/users.json': gone", True),
        ("this needs the admin role (or your own name)", False),
        ("10 clips are playing; try again when one ends", False),
        ("Method Not Allowed", False),
    ],
)
def test_what_counts_as_a_path(text: str, path: bool) -> None:
    from stereopose.web.error_answers import names_a_path

    assert names_a_path(text) is path
