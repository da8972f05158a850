"""Warnings on site (onsite.warner): the energized zones' hazards, as the fences hold them,
to the speakers and signals that cover their zones, with the side from the worker's
skeleton; nothing for a dead zone, a silent zone or a person only predicted."""

from __future__ import annotations

import numpy as np
import pytest

from modbus_device import IoModule
from rtp_listener import Listener
from stereopose.fence import FenceMonitor
from stereopose.fence.site import parse_site
from stereopose.onsite.calls import near
from stereopose.onsite.modbus import Signal
from stereopose.onsite.phrases import Phrasebook
from stereopose.onsite.rtp import Speaker
from stereopose.onsite.speech import Speech
from stereopose.onsite.warner import Warner, side_of
from stereopose.skeleton import JOINTS
from stereopose.types import Event, People3D
from waiting import wait_until

BUSBAR = {  # west of the origin, a hand's height up
    "name": "busbar",
    "kind": "energized",
    "polygon": [[-2.0, -0.5], [-1.5, -0.5], [-1.5, 0.5], [-2.0, 0.5]],
    "z": [1.0, 2.5],
    "joints": ["left_wrist", "right_wrist"],
    "margin_m": 0.5,
    "voltage_kv": 10,
}
PANEL = {
    "name": "panel",
    "kind": "energized",
    "polygon": [[5.0, 5.0], [6.0, 5.0], [6.0, 6.0], [5.0, 6.0]],
    "z": [0.0, 2.5],
    "margin_m": 0.5,
}
J = {name: k for k, name in enumerate(JOINTS)}


def worker(pid: int, x: float, y: float, facing_deg: float, hand=None, predicted=False) -> dict:
    """A standing worker at (x, y) facing `facing_deg` (counter-clockwise from +x), his left
    wrist at `hand` (x, y, z) or beside his hip."""
    f = np.radians(facing_deg)
    right = np.array([np.sin(f), -np.cos(f)])  # his right, on the floor
    joints = np.tile([x, y, 1.2], (17, 1)).astype(float)
    for side, sign in (("left", -1), ("right", 1)):
        for part, z, w in (("shoulder", 1.45, 0.2), ("hip", 0.95, 0.15), ("ankle", 0.05, 0.1)):
            joints[J[f"{side}_{part}"], :2] = [x, y] + sign * w * right
            joints[J[f"{side}_{part}"], 2] = z
        joints[J[f"{side}_wrist"]] = [*([x, y] + sign * 0.25 * right), 0.9]
    if hand is not None:
        joints[J["left_wrist"]] = hand
    return {"id": pid, "joints": joints, "predicted": predicted}


def people(frame: int, *workers: dict) -> People3D:
    J3 = np.array([w["joints"] for w in workers], float).reshape(-1, 17, 3)
    P = len(workers)
    return People3D(
        frame=frame,
        joints=J3,
        conf=np.ones((P, 17)),
        ids=np.array([w["id"] for w in workers], np.int64),
        reprojection_px=np.full((P, 17), np.nan),
        views=np.full((P, 17), 2),
        detections=np.zeros((P, 0), np.int64),
        predicted=np.array([w["predicted"] for w in workers], bool),
        t=frame * 0.05,
    )


def test_the_side_of_a_hazard_for_the_worker():
    east = 0.0
    assert side_of(np.array([1.0, 0.1]), east) == "ahead"
    assert side_of(np.array([-1.0, 0.0]), east) == "behind"
    assert side_of(np.array([0.0, 1.0]), east) == "left"
    assert side_of(np.array([0.2, -1.0]), east) == "right"
    assert side_of(np.array([0.0, 1.0]), 90.0) == "ahead"
    assert side_of(np.array([-1.0, 0.0]), 90.0) == "left"  # facing north, west is left
    assert side_of(np.array([np.nan, 0.0]), 0.0) == "nearby"
    assert side_of(np.array([1.0, 0.0]), float("nan")) == "nearby"


class Rig:
    """The site, its fences and a warner with real speakers (to UDP listeners) and a real
    Modbus IO module."""

    def __init__(self, site_extra=None, zones=(BUSBAR, PANEL), dead=()):
        self.ears = {"pa_busbar": Listener(), "pa_panel": Listener()}
        self.module = IoModule().start()
        doc = {
            "zones": [dict(z) for z in zones],
            "warnings": {"repeat_s": 1.0},
            "speakers": [
                {"name": "pa_busbar", "url": f"rtp://127.0.0.1:{self.ears['pa_busbar'].port}",
                 "zones": ["busbar"]},
                {"name": "pa_panel", "url": f"rtp://127.0.0.1:{self.ears['pa_panel'].port}",
                 "zones": ["panel"]},
            ],
            "signals": [{"name": "tower", "host": "127.0.0.1", "port": self.module.port,
                         "coils": {"beacon": 0, "siren": 1}, "zones": ["busbar"]}],
            **(site_extra or {}),
        }  # fmt: skip
        self.site = parse_site(doc)
        w = self.site.warnings
        self.fences = FenceMonitor(self.site, fps=20.0)
        self.speakers = {s.name: Speaker(s, w.repeat_s) for s in w.speakers}
        self.told: list = []
        self.signals = {
            g.name: Signal(g, on_health=lambda *a: warner.on_health(*a)) for g in w.signals
        }
        self.published: list[dict] = []
        self.dead = set(dead)
        warner = Warner(
            self.site.zones, w, Phrasebook(w, self.site.zones, Speech()), self.speakers,
            self.signals, safe=lambda: self.dead, publish=self.published.append,
        )  # fmt: skip
        self.warner = warner
        self.frame = 0

    def step(self, *workers: dict) -> list:
        p = people(self.frame, *workers)
        self.fences.update(p)
        events = self.warner.step(p.t, self.frame, p, self.fences)
        self.frame += 1
        return events

    def close(self):
        self.warner.close()
        self.module.stop()


@pytest.fixture
def rig():
    r = Rig()
    yield r
    r.close()


def test_a_hand_near_the_busbar_is_said_on_its_speaker_alone_and_lights_its_beacon(rig):
    near = worker(1, 0.0, 0.0, 90.0, hand=(-1.2, 0.0, 1.3))  # 0.3 m east of it, facing north
    for _ in range(4):  # past the fences' debounce
        rig.step(near)
    (h,) = rig.warner.hazards(people(rig.frame, near), rig.fences)
    assert (h.zone, h.kind, h.priority, h.side) == ("busbar", "approach", 2, "left")
    assert h.distance_m == pytest.approx(0.3)
    wait_until(lambda: rig.speakers["pa_busbar"].figures["packets"] > 5, "the busbar's page")
    wait_until(lambda: rig.module.coils(0, 2) == [True, True], "its beacon and siren on")
    assert rig.speakers["pa_panel"].figures["packets"] == 0  # it covers another zone
    doc = rig.published[-1]["warnings"]
    assert doc == [{**h.as_dict(), "speakers": ["pa_busbar"], "signals": ["tower"]}]
    # the hand back at his side: quiet and off within a step of the fences' exit
    away = worker(1, 0.0, 0.0, 90.0)
    for _ in range(6):
        rig.step(away)
    assert not rig.warner.hazards(people(rig.frame, away), rig.fences)
    wait_until(lambda: rig.speakers["pa_busbar"].sounding is None, "the page ended")
    wait_until(lambda: rig.module.coils(0, 2) == [False, False], "beacon and siren off")
    assert rig.published[-1]["warnings"] == []


def test_inside_is_more_urgent_than_near_and_says_so():
    r = Rig()
    try:
        near = worker(1, 0.0, 0.0, 90.0, hand=(-1.2, 0.0, 1.3))
        inside = worker(2, -1.2, 3.0, 0.0, hand=(-1.8, 0.2, 1.5))
        for _ in range(4):
            r.step(near, inside)
        hz = r.warner.hazards(people(r.frame, near, inside), r.fences)
        assert [(h.person, h.kind, h.priority) for h in hz] == [(2, "enter", 1), (1, "approach", 2)]
        wait_until(lambda: r.speakers["pa_busbar"].sounding == ("busbar", "enter", 2), "P1 said")
    finally:
        r.close()


@pytest.mark.parametrize("why", ["dead", "silent", "predicted", "priority"])
def test_no_warning_for_a_dead_or_silent_zone_a_predicted_person_or_another_priority(why):
    zone = {**BUSBAR, "on_site": False} if why == "silent" else BUSBAR
    extra = {"warnings": {"repeat_s": 1.0, "priorities": [1]}} if why == "priority" else None
    r = Rig(site_extra=extra, zones=(zone, PANEL), dead={"busbar"} if why == "dead" else ())
    try:
        seen = worker(1, 0.0, 0.0, 90.0, hand=(-1.2, 0.0, 1.3))
        for _ in range(4):
            r.step(seen)
        if why == "predicted":  # seen near until now; this step only predicted
            hidden = {**seen, "predicted": True}
            r.step(hidden)
            assert r.warner.hazards(people(r.frame, hidden), r.fences) == []
            return
        assert r.warner.hazards(people(r.frame, seen), r.fences) == []
        assert r.speakers["pa_busbar"].figures["messages"] == 0
        assert r.module.coils(0, 2) == [False, False]
    finally:
        r.close()


def test_a_signal_down_is_an_event_once_and_back_again(rig):
    rig.module.stop()
    rig.step(worker(1, 0.0, 0.0, 90.0, hand=(-1.2, 0.0, 1.3)))
    events: list = []
    wait_until(lambda: events.extend(rig.step(worker(1, 0.0, 0.0, 90.0))) or events, "down")
    assert [(e.type, e.kind, e.source) for e in events] == [
        ("warning_output_down", "service", "tower")
    ]
    rig.module = IoModule(port=rig.module.port).start()
    wait_until(
        lambda: events.extend(rig.step(worker(1, 0.0, 0.0, 90.0))) or len(events) > 1,
        "back",
        timeout_s=10,
    )
    assert events[-1].type == "warning_output_back"


# --- calls, silences and tests ------------------------------------------------------------------


def _event(type_: str, person: int, t: float, **more) -> Event:
    kind = "ticket" if type_.startswith("step_") else "behaviour"
    more.setdefault("zone", "")
    return Event(t=t, frame=0, person=person, kind=kind, type=type_, onset_t=t, **more)


def test_a_silenced_speaker_and_signal_stay_quiet_while_the_other_speakers_warn(rig):
    near = worker(1, 0.0, 0.0, 90.0, hand=(-1.2, 0.0, 1.3))
    p = people(0, near)
    for _ in range(4):
        p = people(rig.frame, near)
        rig.fences.update(p)
        rig.warner.step(p.t, rig.frame, p, rig.fences, silenced={"pa_busbar", "tower"})
        rig.frame += 1
    assert rig.warner.hazards(p, rig.fences)  # the hazard is there: only its outputs are silent
    assert rig.speakers["pa_busbar"].figures["messages"] == 0
    assert rig.module.coils(0, 2) == [False, False]
    assert rig.warner.now()["warnings"][0]["speakers"] == []
    rig.step(near)  # the silence over: said and lit at once
    wait_until(lambda: rig.speakers["pa_busbar"].figures["packets"] > 5, "the busbar's page")
    wait_until(lambda: rig.module.coils(0, 2) == [True, True], "its beacon and siren on")


def test_a_test_says_the_test_message_once_and_pulses_a_signal():
    r = Rig(site_extra={"warnings": {"repeat_s": 30.0}})
    ear = r.ears["pa_panel"]
    try:
        idle = worker(1, 0.0, 0.0, 90.0)
        r.warner.test("pa_panel", 0.0)
        r.warner.test("tower", 0.0)
        r.step(idle)
        assert r.warner.sounding("pa_panel") is False  # a test is no warning: others may come
        wait_until(lambda: r.module.coils(0, 2) == [True, True], "the tower pulsed")
        wait_until(lambda: r.speakers["pa_panel"].figures["messages"] == 1, "the test said")
        wait_until(lambda: r.speakers["pa_panel"].sounding is None, "the test's end")
        test = r.warner.book.message(None, "test")
        ear.take(lambda: len(ear.packets) >= -(-len(test) // 160))
        assert len(ear.packets) == -(-len(test) // 160)  # once, whole
        assert r.speakers["pa_busbar"].figures["packets"] == 0
        while r.frame * 0.05 < 3.2:  # past the pulse's 3 s on the step's clock
            r.step(idle)
        wait_until(lambda: r.module.coils(0, 2) == [False, False], "the pulse's end")
        assert r.speakers["pa_panel"].figures["messages"] == 1
    finally:
        r.close()


def test_a_person_down_is_called_until_he_is_up_and_a_p1_cuts_into_a_p3(rig):
    idle = worker(1, 0.0, 0.0, 90.0)
    # a step done in the wrong position at the busbar (P3): said on the busbar's speaker
    wrong = _event("step_wrong_position", 1, 0.0, ticket="T1", step="rack_out", zone="busbar")
    p = people(rig.frame, idle)
    rig.fences.update(p)
    rig.warner.step(p.t, rig.frame, p, rig.fences, events=[wrong])
    rig.frame += 1
    speaker = rig.speakers["pa_busbar"]
    wait_until(lambda: speaker.sounding == ("step_wrong_position", "T1", "rack_out"), "P3")
    assert rig.speakers["pa_panel"].figures["messages"] == 0
    assert rig.warner.now()["calls"][0]["priority"] == 3
    # a hand inside the busbar (P1) cuts into it at the next packet
    inside = worker(1, -1.2, 0.0, 180.0, hand=(-1.8, 0.0, 1.5))
    for _ in range(4):
        rig.step(inside)
    wait_until(lambda: speaker.sounding == ("busbar", "enter", 1), "the P1 cut in")
    assert speaker.figures["cut_in"] >= 1
    # a person down: a call for help (P1) on every speaker (none hung near him: all)
    down = _event("person_down", 2, rig.frame * 0.05, position=(5.5, 4.0))
    fallen = worker(2, 5.5, 4.0, 0.0)
    p = people(rig.frame, idle, fallen)
    rig.fences.update(p)
    rig.warner.step(p.t, rig.frame, p, rig.fences, events=[down])
    rig.frame += 1
    panel = rig.speakers["pa_panel"]
    wait_until(lambda: panel.sounding == ("person_down", 2), "the call for help")
    calls = [(c["kind"], c["person"], c["priority"]) for c in rig.warner.now()["calls"]]
    assert calls == [("person_down", 2, 1), ("step_wrong_position", 1, 3)]  # the P3 not said yet
    up = _event("person_up", 2, rig.frame * 0.05)
    p = people(rig.frame, idle, fallen)
    rig.fences.update(p)
    rig.warner.step(p.t, rig.frame, p, rig.fences, events=[up])
    assert [c["kind"] for c in rig.warner.now()["calls"]] == ["step_wrong_position"]
    wait_until(lambda: panel.sounding is None, "the call ended")


def test_the_speakers_near_a_place():
    specs = parse_site(
        {
            "zones": [BUSBAR, PANEL],
            "speakers": [
                {
                    "name": "hung",
                    "url": "rtp://127.0.0.1:5004",
                    "zones": ["panel"],
                    "position": [40.0, 40.0],
                },
                {"name": "west", "url": "rtp://127.0.0.1:5006", "zones": ["busbar"]},
                {"name": "east", "url": "rtp://127.0.0.1:5008", "zones": ["panel"]},
            ],
        }
    )
    zones, speakers = specs.zones, specs.warnings.speakers
    assert near((41.0, 40.0), speakers, zones) == {"hung"}  # hung 1 m away
    assert near((-15.0, 0.0), speakers, zones) == {"west"}  # the busbar 13 m, the panel 21
    assert near((0.0, 0.0), speakers, zones) == {"hung", "west", "east"}  # both zones near
    assert near((500.0, 0.0), speakers, zones) == {"hung", "west", "east"}  # nobody near: all
    assert near(None, speakers, zones) == {"hung", "west", "east"}
