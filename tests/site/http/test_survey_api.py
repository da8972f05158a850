"""The surveyed points over the API on a real server, against a simulated yard with known
points: an admin saves the points and the clicks, solves (every camera's error, each click's
residual, the knocked camera's move), accepts, and the keeper applies the rig at the next step,
written beside the calibration; every role reads, only an admin writes; bad files and clicks
are 400 naming the key, a camera that cannot be placed 422 naming it."""

from __future__ import annotations

import time

import httpx
import pytest

from consoled import PASSWORDS, console_server
from knocked import surveyed_yard
from stereopose.calibration.poses import pose_change
from stereopose.site.health.calib_keeper import KeeperDesk
from stereopose.site.http.app import Desks

pytestmark = pytest.mark.slow


def _solved(c: httpx.Client, headers: dict) -> httpx.Response:
    """POST /api/survey/solve, then GET it while it is being solved (202): the last answer."""
    r = c.post("/api/survey/solve", headers=headers)
    deadline = time.monotonic() + 120
    while r.status_code == 202 and time.monotonic() < deadline:
        assert r.json()["state"] == "solving"
        time.sleep(0.1)
        r = c.get("/api/survey/solve", headers=headers)
    return r


def _login(c: httpx.Client, name: str) -> dict:
    token = c.post("/api/login", json={"username": name, "password": PASSWORDS[name]}).json()
    return {"Authorization": f"Bearer {token['token']}"}


def test_the_surveyed_points_place_the_rig_while_serving(tmp_path) -> None:
    truth, doc, clicks, keeper, applied = surveyed_yard(tmp_path)
    desk = KeeperDesk()
    desk.attach(keeper)
    with (
        console_server(tmp_path / "out", app_kw={"desks": Desks(calibration=desk)}) as s,
        httpx.Client(base_url=s.url, timeout=60) as c,
    ):
        admin, viewer = _login(c, "ada"), _login(c, "vera")
        assert c.get("/api/survey", headers=viewer).json()["points"] == {}
        assert c.put("/api/survey", json=doc, headers=viewer).status_code == 403
        assert c.post("/api/survey/solve", headers=admin).status_code == 422
        # a click of a point the file does not have, a camera the rig does not have
        bad = {**doc, "cameras": {**doc["cameras"], "cam01": {"P99": [1.0, 2.0]}}}
        r = c.put("/api/survey", json=bad, headers=admin)
        assert r.status_code == 400 and "cameras.cam01.P99" in r.json()["detail"]
        bad = {**doc, "cameras": {**doc["cameras"], "cam9": doc["cameras"]["cam01"]}}
        r = c.put("/api/survey", json=bad, headers=admin)
        assert r.status_code == 400 and "cam9" in r.json()["detail"]
        assert c.put("/api/survey", json=doc, headers=admin).json() == {"saved": True}
        back = c.get("/api/survey", headers=viewer).json()
        assert back["points"] == doc["points"] and back["cameras"] == doc["cameras"]
        assert c.post("/api/survey/accept", headers=admin).status_code == 404
        solved = _solved(c, admin).json()
        assert solved.pop("state") == "solved" and solved.pop("job") >= 1
        assert set(solved["cameras"]) == set(truth.names) and solved["unplaced"] == []
        assert max(cam["rms_px"] for cam in solved["cameras"].values()) < 3.0
        assert 1.7 < solved["cameras"]["cam02"]["turned_deg"] < 2.3  # bumped back
        assert all(solved["cameras"][n]["turned_deg"] < 0.3 for n in truth.names if n != "cam02")
        assert set(solved["residuals_px"]["cam02"]) == set(clicks["cam02"])
        assert c.get("/api/survey", headers=viewer).json()["solved"] == solved
        assert c.post("/api/survey/accept", headers=viewer).status_code == 403
        ok = c.post("/api/survey/accept", headers=admin).json()
        assert ok == {"cameras": list(truth.names), "by": "ada"}
        assert c.post("/api/survey/accept", headers=admin).status_code == 404
    assert applied == []  # at the next step, not before
    events = keeper.update(1, 0.1, {}, [])
    assert [e.camera for e in events] == list(truth.names)
    assert all(e.type == "calibration_corrected" for e in events)
    assert events[0].result == {**events[0].result, "accepted_by": "ada"}
    (rig,) = applied
    turned, _ = pose_change(truth["cam02"], rig["cam02"])
    assert turned < 0.3
    assert keeper.written is not None and keeper.written.name == "calib.corrected.toml"
    assert (tmp_path / "out" / "survey" / "points.toml").is_file()


def test_a_camera_with_too_few_clicks_is_named_and_the_others_placed(tmp_path) -> None:
    _, doc, _, keeper, _ = surveyed_yard(tmp_path, bumped_deg=0.0)
    doc["cameras"]["cam04"] = dict(sorted(doc["cameras"]["cam04"].items())[:4])
    desk = KeeperDesk()
    desk.attach(keeper)
    with (
        console_server(tmp_path / "out", app_kw={"desks": Desks(calibration=desk)}) as s,
        httpx.Client(base_url=s.url, timeout=60) as c,
    ):
        admin = _login(c, "ada")
        assert c.put("/api/survey", json=doc, headers=admin).status_code == 200
        r = _solved(c, admin)
        assert r.status_code == 200, r.text
        solved = r.json()
        assert "cam04" in solved["unplaced"] and "cam04" not in solved["cameras"]
        assert "camera cam04: 4 surveyed point(s)" in solved["not_placed"]["cam04"]
        assert any("cam04 not placed" in w for w in solved["warnings"])


def test_a_long_solve_holds_no_request(tmp_path, monkeypatch) -> None:
    """The solve on the desk's own thread: the POST answers at once (202), the server answers
    others meanwhile, and the answer is fetched when done; a second POST while it runs is the
    same solve."""
    monkeypatch.setattr("stereopose.site.http.api.calibration.SOLVE_WAIT_S", 0.0)
    _, doc, _, keeper, _ = surveyed_yard(tmp_path, bumped_deg=0.0)
    desk = KeeperDesk()
    desk.attach(keeper)
    with (
        console_server(tmp_path / "out", app_kw={"desks": Desks(calibration=desk)}) as s,
        httpx.Client(base_url=s.url, timeout=60) as c,
    ):
        admin, viewer = _login(c, "ada"), _login(c, "vera")
        assert c.get("/api/survey/solve", headers=viewer).status_code == 404  # none begun
        # a points file over the server's bound on a body: 413 with the limit, nothing kept
        huge = {"points": {f"P{i}": [float(i), 0.0, 0.0] for i in range(60_000)}, "cameras": {}}
        r = c.put("/api/survey", json=huge, headers=admin)
        assert r.status_code == 413 and "over 1048576 bytes" in r.text, r.text[:200]
        assert c.get("/api/survey", headers=viewer).json()["points"] == {}
        assert c.put("/api/survey", json=doc, headers=admin).status_code == 200
        first = c.post("/api/survey/solve", headers=admin)
        assert first.status_code == 202 and first.json()["state"] == "solving"
        again = c.post("/api/survey/solve", headers=admin).json()
        assert again["job"] == first.json()["job"] or again["state"] == "solved"
        assert c.get("/api/survey", headers=viewer).status_code == 200  # not held meanwhile
        deadline = time.monotonic() + 120
        while (r := c.get("/api/survey/solve", headers=viewer)).status_code == 202:
            assert time.monotonic() < deadline, "the solve never ended"
            time.sleep(0.1)
        assert r.status_code == 200 and r.json()["state"] == "solved"
        assert r.json()["job"] == first.json()["job"] and r.json()["unplaced"] == []
