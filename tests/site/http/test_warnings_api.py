"""The warnings on site over the API on a real server (site.http.api.warnings): every user
reads what sounds and each output's state; only an admin silences, lifts or tests, each act
an event at the next step; a silenced beacon stays off while its hazard lasts; bad acts are
answered with their problem."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from consoled import console_server
from modbus_device import IoModule
from rtp_listener import Listener
from stereopose.fence import FenceMonitor
from stereopose.fence.site import parse_site
from stereopose.onsite.service import OnSite
from stereopose.site.http.api.warnings import WarningsDesk
from stereopose.site.http.app import Desks
from stereopose.skeleton import JOINTS
from stereopose.types import People3D
from waiting import wait_until

BUSBAR = {
    "name": "busbar",
    "kind": "energized",
    "polygon": [[-2.0, -0.5], [-1.5, -0.5], [-1.5, 0.5], [-2.0, 0.5]],
    "z": [1.0, 2.5],
    "joints": ["left_wrist", "right_wrist"],
    "margin_m": 0.5,
}


def _people(frame: int, hand_near: bool) -> People3D:
    joints = np.tile([0.0, 0.0, 1.0], (1, 17, 1)).astype(float)
    joints[0, JOINTS.index("left_ankle"), 2] = joints[0, JOINTS.index("right_ankle"), 2] = 0.05
    if hand_near:
        joints[0, JOINTS.index("left_wrist")] = (-1.2, 0.0, 1.3)
    return People3D(
        frame=frame,
        joints=joints,
        conf=np.ones((1, 17)),
        ids=np.array([1]),
        reprojection_px=np.full((1, 17), np.nan),
        views=np.full((1, 17), 2),
        detections=np.zeros((1, 0), np.int64),
        predicted=np.zeros(1, bool),
        t=frame * 0.05,
    )


def warned_site(speaker_port: int, module_port: int):
    """The busbar, a speaker covering it (RTP to speaker_port) and a beacon (a Modbus TCP
    IO module at module_port)."""
    return parse_site(
        {
            "zones": [BUSBAR],
            "speakers": [
                {"name": "pa", "url": f"rtp://127.0.0.1:{speaker_port}", "zones": ["busbar"]}
            ],
            "signals": [
                {
                    "name": "tower",
                    "host": "127.0.0.1",
                    "port": module_port,
                    "coils": {"beacon": 0},
                    "zones": ["busbar"],
                }
            ],
        }
    )


def test_only_an_admin_silences_lifts_and_tests_and_each_act_is_logged(tmp_path: Path) -> None:
    ear, module = Listener(), IoModule().start()
    site = warned_site(ear.port, module.port)
    onsite, fences, desk = OnSite(site), FenceMonitor(site, fps=20.0), WarningsDesk()
    frame, events = 0, []

    def step(hand_near: bool = False) -> None:
        nonlocal frame
        p = _people(frame, hand_near)
        fences.update(p)
        events.extend(onsite.step(p.t, frame, p, fences))
        frame += 1

    try:
        with console_server(tmp_path, app_kw={"desks": Desks(warnings=desk)}) as served:
            vera, otto, ada = (served.client(n) for n in ("vera", "otto", "ada"))
            none = vera.get("/api/warnings")  # not built yet (or a site without them)
            assert none.status_code == 200 and none.json()["outputs"] == []
            assert ada.post("/api/warnings/tower/test").status_code == 503
            desk.attach(onsite)
            step()
            wait_until(lambda: module.coils(0) == [False] and onsite._signals["tower"].up, "up")
            doc = vera.get("/api/warnings").json()
            outputs = {o["name"]: o for o in doc["outputs"]}
            assert (
                outputs["pa"]["health"] == "not verifiable" and outputs["tower"]["health"] == "up"
            )
            assert outputs["pa"]["zones"] == ["busbar"] and doc["warnings"] == []
            body = {"minutes": 10, "reason": "beacon lamp replaced"}
            for who in (vera, otto):
                assert who.post("/api/warnings/tower/silence", json=body).status_code == 403
                assert who.post("/api/warnings/tower/test").status_code == 403
            assert ada.post("/api/warnings/nowhere/silence", json=body).status_code == 404
            bad = ada.post("/api/warnings/tower/silence", json={"minutes": 0, "reason": "x"})
            assert bad.status_code == 422
            r = ada.post("/api/warnings/tower/silence", json=body)
            assert r.status_code == 200 and r.json()["silenced"]["by"] == "ada"
            conflict = ada.post("/api/warnings/tower/test")
            assert conflict.status_code == 409 and "silenced" in conflict.json()["detail"]
            for _ in range(5):  # a hand near the busbar: the page, but the beacon stays off
                step(hand_near=True)
            wait_until(lambda: onsite._speakers["pa"].figures["packets"] > 3, "the page")
            assert module.coils(0) == [False]
            doc = vera.get("/api/warnings").json()
            assert doc["silenced"][0]["reason"] == "beacon lamp replaced"
            tower = next(o for o in doc["outputs"] if o["name"] == "tower")
            assert tower["silenced"]["output"] == "tower" and tower["sounding"] == []
            pa = next(o for o in doc["outputs"] if o["name"] == "pa")
            assert [s["zone"] for s in pa["sounding"]] == ["busbar"]
            busy = ada.post("/api/warnings/pa/test")
            assert busy.status_code == 409 and "warning now" in busy.json()["detail"]
            assert ada.delete("/api/warnings/tower/silence").status_code == 200
            assert ada.delete("/api/warnings/tower/silence").status_code == 404
            step(hand_near=True)
            wait_until(lambda: module.coils(0) == [True], "the beacon lit once no longer silenced")
            for _ in range(8):  # the hand away: quiet and off
                step()
            wait_until(lambda: module.coils(0) == [False], "off")
            assert ada.post("/api/warnings/tower/test").status_code == 202
            step()
            wait_until(lambda: module.coils(0) == [True], "the test's pulse")
        acts = [(e.type, e.source, (e.result or {}).get("by")) for e in events if e.source]
        assert acts == [
            ("warning_output_silenced", "tower", "ada"),
            ("warning_output_unsilenced", "tower", "ada"),
            ("warning_output_test", "tower", "ada"),
        ]
    finally:
        onsite.close()
        module.stop()
