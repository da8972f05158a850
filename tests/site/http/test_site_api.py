"""GET/PUT /api/site and its history on a real server, over a real site file (the demo's):
every role reads it; an admin's change is written (its comments kept), versioned, kept in the
history and handed to the frame loop; 400 naming the key with nothing changed, 403 for
operators and viewers and for a cookie without its CSRF header, 409 for a stale version."""

from __future__ import annotations

import contextlib
import json
import shutil
from importlib import resources
from pathlib import Path

import httpx
import numpy as np
import pytest

from consoled import console_server
from stereopose.fence import load_site
from stereopose.fence.site import site_version
from stereopose.site.http.app import Desks
from stereopose.site.site_desk import SiteDesk
from stereopose.types import Camera, Rig

DEMO_SITE = Path(str(resources.files("stereopose") / "data" / "demo_site.toml"))


@pytest.fixture
def desk(tmp_path) -> SiteDesk:
    path = tmp_path / "site.toml"
    shutil.copy(DEMO_SITE, path)
    return SiteDesk(path, load_site(path), tmp_path / "history")


def _busbar_wider(doc: dict) -> dict:
    zones = [dict(z) for z in doc["zones"]]
    zones[0] = {**zones[0], "margin_m": 0.9}
    return {**doc, "zones": zones}


def test_every_role_reads_the_site_and_only_an_admin_changes_it(desk, tmp_path) -> None:
    before = desk.path.read_text()
    with console_server(tmp_path / "out", app_kw={"desks": Desks(site=desk)}) as s:
        for name in ("vera", "otto"):
            with contextlib.closing(s.client(name)) as c:
                got = c.get("/api/site").json()
                assert got["version"] == desk.version
                names = [z["name"] for z in got["site"]["zones"]]
                assert names[:2] == ["overhead_busbar", "work_area"] and len(names) == 4
                r = c.put("/api/site", json={"version": got["version"], "site": got["site"]})
                assert r.status_code == 403
        with httpx.Client(base_url=s.url, timeout=30) as anonymous:
            assert anonymous.get("/api/site").status_code == 401
        with contextlib.closing(s.client("ada")) as c:
            got = c.get("/api/site").json()
            del c.headers["X-CSRF-Token"]  # a cookie session without its CSRF header
            body = {"version": got["version"], "site": _busbar_wider(got["site"])}
            assert c.put("/api/site", json=body).status_code == 403
        assert desk.path.read_text() == before and desk.take() is None
        with contextlib.closing(s.client("ada")) as c:
            r = c.put("/api/site", json=body)
            assert r.status_code == 200, r.text
            version = r.json()["version"]
            assert version == desk.version != got["version"]
            assert c.get("/api/site").json()["site"]["zones"][0]["margin_m"] == 0.9
            history = c.get("/api/site/history").json()["versions"]
            assert [h["version"] for h in history] == [version, got["version"]]
            assert history[0]["by"] == "ada"
            old = c.get(f"/api/site/history/{got['version']}").json()
            assert old["site"]["zones"][0]["margin_m"] == 0.3
            assert c.get("/api/site/history/00ff").status_code == 404
            assert c.get("/api/site/history/not-hex").status_code == 422
            # the same edit again: the version it names is not the current one
            assert c.put("/api/site", json=body).status_code == 409
            # restored: the earlier version's site put over the current one
            r = c.put("/api/site", json={"version": version, "site": old["site"]})
            assert r.status_code == 200 and r.json()["version"] == got["version"]
    text = desk.path.read_text()
    assert "# recording looped as `serve --demo` plays it" in text  # its comments kept
    assert site_version(load_site(desk.path)) == got["version"]
    change = desk.take()
    assert change is not None and change.by == "ada" and change.version == got["version"]
    assert change.old.zones[0].margin_m == 0.3  # what the frame loop still runs
    assert desk.take() is None


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda d: {**d, "zones": [{**d["zones"][0], "polygon": [[0, 0], [1, 1]]}]}, "polygon"),
        (lambda d: {**d, "zones": [{**d["zones"][0], "kind": "lava"}]}, "kind"),
        (lambda d: {**d, "zones": [{**d["zones"][0], "voltage_kv": -3}]}, "voltage_kv"),
        (lambda d: {**d, "speed": 3}, "speed"),
        (lambda d: {**d, "zones": d["zones"][1:]}, "reach_from_work_area"),  # a rule needs it
        (lambda d: {**d, "zones": "everywhere"}, "zones"),
    ],
)
def test_a_bad_site_is_400_naming_the_key_and_changes_nothing(desk, tmp_path, edit, message):
    before, version = desk.path.read_text(), desk.version
    with (
        console_server(tmp_path / "out", app_kw={"desks": Desks(site=desk)}) as s,
        contextlib.closing(s.client("ada")) as c,
    ):
        got = c.get("/api/site").json()
        r = c.put("/api/site", json={"version": got["version"], "site": edit(got["site"])})
        assert r.status_code == 400, r.text
        assert message in r.json()["detail"]
    assert desk.path.read_text() == before and desk.version == version and desk.take() is None
    assert [h["version"] for h in desk.history()] == [version]


def test_without_a_site_file_the_api_says_so(tmp_path) -> None:
    with console_server(tmp_path / "out") as s, contextlib.closing(s.client("vera")) as c:
        assert c.get("/api/site").status_code == 503


def test_a_hand_edit_is_taken_and_a_broken_file_keeps_the_running_site(desk) -> None:
    text = desk.path.read_text()
    desk.path.write_text(text.replace("margin_m = 0.3", "margin_m = 0.5"))
    version = desk.reload()
    assert version is not None and desk.take().new.zones[0].margin_m == 0.5
    assert desk.take_notes() == []
    desk.path.write_text(text.replace("margin_m = 0.3", "margin_m = -1"))
    assert desk.reload() is None and desk.version == version and desk.take() is None
    [(kind, why)] = desk.take_notes()
    assert kind == "site_invalid" and str(desk.path) in why and "margin_m" in why
    desk.path.write_text(text.replace("margin_m = 0.3", "margin_m = 0.5"))
    assert desk.reload() is None  # the same site as running: nothing to take
    assert desk.take_notes() == [("site_valid", f"{desk.path}: loads again")]


def _shifted(cam: Camera, dx: float) -> Camera:
    """The camera moved dx metres along world x."""
    center = cam.center + np.array([dx, 0.0, 0.0])
    return Camera(cam.name, cam.size, cam.matrix, cam.distortions, cam.rotation, -cam.R @ center)


def test_the_zones_in_the_cameras_pictures_and_a_click_back_on_the_floor(tmp_path) -> None:
    from consoled import demo_plan
    from stereopose.geometry.camera import project

    plan = demo_plan(tmp_path)
    path = tmp_path / "site.toml"
    shutil.copy(DEMO_SITE, path)
    desk = SiteDesk(path, load_site(path), tmp_path / "history", rig=plan.rig)
    with (
        console_server(tmp_path / "out", app_kw={"desks": Desks(site=desk)}) as s,
        contextlib.closing(s.client("vera")) as c,
    ):
        got = c.post("/api/site/views", json={}).json()["cameras"]
        assert [v["name"] for v in got] == ["cam01", "cam02", "cam03", "cam04"]
        for view in got:  # the demo's four zones are in view of every camera
            assert all(z["lines"] for z in view["zones"]) and len(view["zones"]) == 4
        # a draft (not saved) is seen too; one that does not check is 400
        draft = {**desk.current()["site"]}
        draft["zones"] = [
            *draft["zones"],
            {
                "name": "new",
                "kind": "restricted",
                "polygon": [[0, 0], [1, 0], [1, 1]],
                "z": [0, 2],
            },
        ]
        got = c.post("/api/site/views", json={"site": draft}).json()["cameras"]
        assert [z["name"] for z in got[0]["zones"]][-1] == "new"
        bad = {**draft, "zones": [{"name": "x", "kind": "lava"}]}
        assert c.post("/api/site/views", json={"site": bad}).status_code == 400
        # a point of cam02's picture back on the floor: the floor point seen there
        cam = plan.rig[1]
        fx, fy = project(np.array([[0.3, -0.2, 0.0]]), cam)[0] / cam.size
        r = c.post("/api/site/floor", json={"camera": "cam02", "x": fx, "y": fy, "z": 0})
        assert r.status_code == 200 and abs(r.json()["x"] - 0.3) < 1e-3
        assert abs(r.json()["y"] + 0.2) < 1e-3
        missing = {"camera": "cam09", "x": 0.5, "y": 0.5}
        assert c.post("/api/site/floor", json=missing).status_code == 404
        # a plane above the camera's height in front of it cannot be met looking down
        up = {"camera": "cam02", "x": fx, "y": fy, "z": 50}
        assert c.post("/api/site/floor", json=up).status_code == 422
        # the cameras placed again (the keeper, the surveyed points): seen through the new rig
        moved = Rig(tuple(_shifted(k, 0.5) if k.name == "cam02" else k for k in plan.rig))
        desk.set_rig(moved)
        r = c.post("/api/site/floor", json={"camera": "cam02", "x": fx, "y": fy, "z": 0})
        assert abs(r.json()["x"] - 0.3) > 0.1  # the same pixel lands elsewhere now


def test_an_endpoints_password_is_never_shown_and_kept_when_the_site_comes_back(tmp_path):
    path = tmp_path / "site.toml"
    endpoint = "opc.tcp://scada:hunter2@10.0.0.6:4840"
    path.write_text(
        DEMO_SITE.read_text().replace(
            "margin_m = 0.3\n",
            "margin_m = 0.3\nstate = { opcua = { endpoint = "
            f'"{endpoint}", node_id = "ns=2;s=QF" }} }}\n',
            1,
        )
    )
    desk = SiteDesk(path, load_site(path), tmp_path / "history")
    with (
        console_server(tmp_path / "out", app_kw={"desks": Desks(site=desk)}) as s,
        contextlib.closing(s.client("ada")) as c,
    ):
        r = c.get("/api/site")
        assert "hunter2" not in r.text and "scada:***@10.0.0.6" in r.text
        assert "hunter2" not in c.get(f"/api/site/history/{desk.version}").text
        got = r.json()
        r = c.put("/api/site", json={"version": got["version"], "site": _busbar_wider(got["site"])})
        assert r.status_code == 200, r.text
        assert (
            endpoint in path.read_text() and desk.site.zones[0].power.points[0].endpoint == endpoint
        )
        # a hidden password the running site does not hold is never written as ***
        moved = json.loads(json.dumps(c.get("/api/site").json()))
        state = moved["site"]["zones"][0]["state"]["points"]["state"]["opcua"]
        state["endpoint"] = "opc.tcp://scada:***@10.0.0.7:4840"
        r = c.put("/api/site", json=moved)
        assert r.status_code == 400 and "give it again" in r.json()["detail"]
    assert "***" not in path.read_text()


def test_the_plans_background_drawing(desk, tmp_path) -> None:
    """An admin puts a drawing under the plan, placed by two of its points; everyone reads it;
    anything that is not a PNG or JPEG, or points not in it, is 400 and keeps what was."""
    import cv2

    drawing = np.full((300, 400, 3), 255, np.uint8)
    png = cv2.imencode(".png", drawing)[1].tobytes()
    jpg = cv2.imencode(".jpg", drawing)[1].tobytes()
    points = "10,290,0,0,390,290,19,0"
    # a small file whose header says 60000 x 60000: refused before it is decoded
    huge_png = png[:16] + (60000).to_bytes(4, "big") * 2 + png[24:]
    with console_server(tmp_path / "out", app_kw={"desks": Desks(site=desk)}) as s:
        admin, viewer = s.client("ada"), s.client("vera")
        try:
            assert viewer.get("/api/site/background").status_code == 404
            # no drawing is the usual state: answered as one (a page asking logs no error)
            none = viewer.get("/api/site/background/placement")
            assert none.status_code == 200 and none.json() == {"drawing": False}
            url = f"/api/site/background?points={points}"
            png_type = {"Content-Type": "image/png"}
            assert viewer.put(url, content=png, headers=png_type).status_code == 403
            r = admin.put(url, content=png, headers=png_type)
            assert r.status_code == 200 and r.json()["size"] == [400, 300]
            got = viewer.get("/api/site/background")
            assert got.content == png and got.headers["content-type"] == "image/png"
            placement = viewer.get("/api/site/background/placement").json()
            assert placement["points"] == [[10, 290, 0, 0], [390, 290, 19, 0]]
            assert placement["drawing"] is True and placement["size"] == [400, 300]
            for body, pts, why in (
                (b"GIF89a...", points, "PNG or a JPEG"),
                (png[:60], points, "decodes"),
                (png, "10,290,0,0,500,290,19,0", "not in the 400x300 drawing"),
                (png, "10,290,0,0,12,290,19,0", "apart"),
                (png, "1,2,3", "8 finite numbers"),
                (huge_png, points, "1 to 5000 a side"),
                (png, "a,b", "8 numbers"),
            ):
                r = admin.put(f"/api/site/background?points={pts}", content=body)
                assert r.status_code == 400 and why in r.json()["detail"], (why, r.text)
            assert viewer.get("/api/site/background").content == png  # kept
            r = admin.put(url, content=jpg, headers={"Content-Type": "image/jpeg"})
            assert r.status_code == 200
            assert viewer.get("/api/site/background").headers["content-type"] == "image/jpeg"
            assert admin.delete("/api/site/background").json() == {"deleted": True}
            assert admin.delete("/api/site/background").status_code == 404
            assert viewer.get("/api/site/background/placement").json() == {"drawing": False}
        finally:
            admin.close()
            viewer.close()
