"""Each behaviour rule's timing and debounce, frame by frame on synthetic skeletons."""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Sequence

import numpy as np
import pytest

import bodies as b
from stereopose.behaviour import parse_rules
from stereopose.behaviour.rules import HANDOVER_S, BehaviourMonitor
from stereopose.skeleton import RIGHT_SHOULDER, RIGHT_WRIST
from stereopose.types import Event
from stereopose.zones import Zone

FPS = 25.0
DT = 1.0 / FPS
# a panel along the wall x = 0 (energized), the work area in front of it, and a far corner
ZONES = (
    Zone(
        "panel", "energized", np.array([[0.0, 2.0], [0.6, 2.0], [0.6, 4.0], [0.0, 4.0]]), (0.0, 2.5)
    ),
    Zone(
        "front", "work_area", np.array([[0.6, 2.0], [1.6, 2.0], [1.6, 4.0], [0.6, 4.0]]), (0.0, 2.5)
    ),
    Zone(
        "corner",
        "restricted",
        np.array([[8.0, 6.0], [9.0, 6.0], [9.0, 7.0], [8.0, 7.0]]),
        (0.0, 2.5),
    ),
)
FACING_PANEL = math.pi  # facing -x, toward the panel


def monitor(*rules: dict, lost_s: float = 3.0) -> BehaviourMonitor:
    return BehaviourMonitor(parse_rules(list(rules), "test", ZONES), ZONES, FPS, lost_s)


Scene = Callable[[float], dict[int, np.ndarray]]


def run(
    mon: BehaviourMonitor,
    scene: Scene,
    seconds: float,
    *,
    start: float = 0.0,
    hidden: Callable[[float, int], bool] | None = None,
) -> list[Event]:
    """Steps the monitor through `scene(t)` ({id: joints}) at FPS; hidden(t, id): that person
    is predicted (not seen) at t."""
    events: list[Event] = []
    n0 = round(start * FPS)
    for k in range(n0, n0 + round(seconds * FPS)):
        t = k * DT
        bodies = scene(t)
        pred = {i: hidden(t, i) for i in bodies} if hidden else None
        evs, postures = mon.step(t, k, b.people(k, bodies, t, pred))
        assert set(postures) == set(bodies)
        events += evs
    return events


def types(events: Sequence[Event]) -> list[str]:
    return [e.type for e in events]


def fall(
    t0: float,
    fall_s: float = 0.7,
    heading: float = 0.0,
    xy=(3.0, 3.0),
    up_at: float | None = None,
    missing: Sequence[int] = (),
) -> Scene:
    """A worker standing at xy who falls backwards at t0 (rotating to the floor in fall_s) and
    lies there, getting up at up_at; the joints `missing` are not seen once on the floor."""
    body = b.standing(xy=xy, heading=heading)

    def scene(t: float) -> dict[int, np.ndarray]:
        if up_at is not None and t >= up_at:
            return {1: body}
        if t < t0:
            return {1: body}
        a = min(1.0, (t - t0) / fall_s)
        J = b.tipped(body, heading, 0.5 * np.pi * a * a)
        if a >= 1.0 and missing:
            J = J.copy()
            J[list(missing)] = np.nan
        return {1: J}

    return scene


# --- person_down ---


def test_a_fall_then_down_for_down_s_is_one_event_and_rising_is_person_up() -> None:
    mon = monitor({"name": "man_down", "type": "person_down", "down_s": 3.0, "up_s": 1.0})
    events = run(mon, fall(1.0, up_at=8.0), 12.0)
    assert types(events) == ["person_down", "person_up"]
    down, up = events
    # the fall lands about 1.6 s (0.7 s of falling, hips below floor_m near the end)
    assert 1.4 <= down.onset_t <= 1.75
    assert down.t == pytest.approx(down.onset_t + 3.0, abs=DT + 1e-9)
    assert down.rule == "man_down" and down.kind == "behaviour" and down.posture == "lying"
    assert down.speed_m_s > 1.0 and down.person == 1 and down.zone == ""
    assert down.position is not None
    assert up.onset_t == pytest.approx(8.0, abs=1e-9)
    assert up.t == pytest.approx(9.0, abs=DT + 1e-9)  # standing up_s
    assert up.duration_s == pytest.approx(8.0 - down.onset_t, abs=1e-6)


def test_a_fall_with_the_person_up_before_down_s_raises_nothing() -> None:
    mon = monitor({"name": "d", "type": "person_down", "down_s": 3.0, "up_s": 0.5})
    assert run(mon, fall(1.0, up_at=3.0), 8.0) == []


def test_up_must_last_up_s() -> None:
    """Rising for a moment (shorter than up_s) and falling back is still down."""
    body = b.standing(xy=(3.0, 3.0))
    flat = b.tipped(body, 0.0, 0.5 * np.pi)
    base = fall(1.0)

    def scene(t: float) -> dict[int, np.ndarray]:
        if 6.0 <= t < 6.4:  # up for 0.4 s, down again (a slow lowering: no new fall)
            return {1: body}
        if 6.4 <= t < 7.4:
            return {1: b.tipped(body, 0.0, 0.5 * np.pi * (t - 6.4))}
        if t >= 7.4:
            return {1: flat}
        return base(t)

    mon = monitor({"name": "d", "type": "person_down", "down_s": 3.0, "up_s": 1.0})
    events = run(mon, scene, 12.0)
    assert types(events) == ["person_down"]


@pytest.mark.parametrize(
    "end",
    [
        pytest.param(b.kneeling(xy=(3.0, 3.0)), id="kneeling"),
        pytest.param(b.squatting(xy=(3.0, 3.0)), id="squatting"),
        pytest.param(b.kneeling(xy=(3.0, 3.0), lean=1.3), id="kneeling-bent-into-panel"),
        pytest.param(b.standing(xy=(3.0, 3.0), bend=1.4), id="bending"),
        pytest.param(b.sitting_floor(xy=(3.0, 3.0)), id="sitting-on-floor"),
    ],
)
def test_getting_down_quickly_to_work_is_not_a_fall(end: np.ndarray) -> None:
    """Standing, then in 0.4 s (fast: the hips drop at > 1 m/s) kneeling, squatting, bending
    or sitting, and staying there: no person_down."""
    stand = b.standing(xy=(3.0, 3.0))
    mon = monitor({"name": "d", "type": "person_down", "down_s": 3.0})
    drops = []

    def scene(t: float) -> dict[int, np.ndarray]:
        if t < 1.0:
            return {1: stand}
        a = min(1.0, (t - 1.0) / 0.4)
        return {1: (1 - a) * stand + a * end}

    for k in range(round(12.0 * FPS)):
        t = k * DT
        events, postures = mon.step(t, k, b.people(k, scene(t), t))
        assert events == []
        drops.append(postures[1].drop_m_s)
    assert np.nanmax(drops) > 1.0 or "bending" in str(postures[1].posture)


def test_lying_down_slowly_to_work_under_equipment_is_not_a_fall() -> None:
    """Sitting down over 2 s, then lying back over 2 s, and lying there: no fall was seen."""
    stand, sit = b.standing(xy=(3.0, 3.0)), b.sitting_floor(xy=(3.0, 3.0))
    lie = b.lying(xy=(3.0 + 0.9, 3.0), heading=0.0)

    def scene(t: float) -> dict[int, np.ndarray]:
        if t < 1.0:
            return {1: stand}
        if t < 3.0:
            a = (t - 1.0) / 2.0
            return {1: (1 - a) * stand + a * sit}
        a = min(1.0, (t - 3.0) / 2.0)
        return {1: (1 - a) * sit + a * lie}

    mon = monitor({"name": "d", "type": "person_down", "down_s": 3.0})
    events, posture = [], None
    for k in range(round(30 * FPS)):
        t = k * DT
        evs, postures = mon.step(t, k, b.people(k, scene(t), t))
        events += evs
        posture = postures[1].posture
    assert events == [] and posture == "lying"


def test_a_fall_seen_with_joints_missing_and_noise() -> None:
    """A fall where few cameras see the body: 2 cm noise, a quarter of the joints missing at
    random every frame, and the whole lower body gone once on the floor."""
    rng = np.random.default_rng(7)
    base = fall(1.0, missing=[11, 12, 13, 14, 15, 16])

    def scene(t: float) -> dict[int, np.ndarray]:
        return {1: b.noisy(base(t)[1], rng, 0.02, missing=0.25)}

    mon = monitor({"name": "d", "type": "person_down", "down_s": 3.0})
    events = run(mon, scene, 8.0)
    assert types(events) == ["person_down"]
    assert events[0].t == pytest.approx(events[0].onset_t + 3.0, abs=DT + 1e-9)
    assert events[0].t <= 1.0 + 0.7 + 3.0 + 0.5


def test_a_person_down_unseen_is_still_raised_on_time() -> None:
    """The body hidden (the tracker predicts it) once it is on the floor: the alarm comes at
    down_s all the same, once."""
    mon = monitor({"name": "d", "type": "person_down", "down_s": 3.0}, lost_s=10.0)
    events = run(mon, fall(1.0), 8.0, hidden=lambda t, i: t >= 2.5)
    assert types(events) == ["person_down"]


def test_a_person_down_whose_track_ended_is_not_up() -> None:
    """Their track ends (not output at all) before down_s: the alarm still comes; no
    person_up ever."""
    mon = monitor({"name": "d", "type": "person_down", "down_s": 3.0}, lost_s=5.0)
    scene = fall(1.0)
    events = run(mon, scene, 2.5)
    events += run(mon, lambda t: {}, 10.0, start=2.5)
    assert types(events) == ["person_down"]


# --- lone_worker ---


@functools.cache
def _at(x: float, y: float, heading: float, kw: tuple) -> np.ndarray:
    J = b.standing(xy=(x, y), heading=heading, **dict(kw))
    J.setflags(write=False)
    return J


def at(x: float, y: float, heading: float = FACING_PANEL, **kw) -> np.ndarray:
    """A standing worker at (x, y) (the same array for the same arguments: read-only)."""
    return _at(x, y, heading, tuple(sorted(kw.items())))


def test_lone_worker_after_lone_s_and_its_end_when_a_buddy_comes() -> None:
    rule = {
        "name": "two_man",
        "type": "lone_worker",
        "zones": ["panel"],
        "buddy_m": 3.0,
        "lone_s": 5.0,
        "exit_s": 1.0,
    }

    def scene(t: float) -> dict[int, np.ndarray]:
        people = {1: at(1.0, 3.0)}  # 0.4 m from the panel
        if t >= 8.0:
            people[2] = at(2.5, 3.0)  # within buddy_m
        return people

    events = run(monitor(rule), scene, 12.0)
    assert types(events) == ["lone_worker", "lone_worker_end"]
    lone, end = events
    assert lone.onset_t == 0.0 and lone.t == pytest.approx(5.0, abs=1e-9)
    assert lone.zone == "panel" and lone.nearest_m is None and lone.rule == "two_man"
    assert end.onset_t == pytest.approx(8.0) and end.t == pytest.approx(9.0, abs=1e-9)
    assert end.nearest_m == pytest.approx(1.5, abs=0.01)
    assert end.duration_s == pytest.approx(9.0, abs=1e-9)


def test_lone_worker_needs_company_within_buddy_m_and_being_near_the_zone() -> None:
    rule = {
        "name": "l",
        "type": "lone_worker",
        "zones": ["panel"],
        "buddy_m": 3.0,
        "lone_s": 2.0,
        "approach_m": 1.0,
    }
    # a buddy 2 m away all along: nothing
    assert run(monitor(rule), lambda t: {1: at(1.0, 3.0), 2: at(3.0, 3.0)}, 6.0) == []
    # a second person far away (5 m) is no company
    events = run(monitor(rule), lambda t: {1: at(1.0, 3.0), 2: at(6.0, 3.0)}, 6.0)
    assert types(events) == ["lone_worker"]
    assert events[0].person == 1 and events[0].nearest_m == pytest.approx(5.0, abs=0.01)
    # alone but 3 m from the panel (beyond approach_m): nothing
    assert run(monitor(rule), lambda t: {1: at(4.0, 3.0)}, 6.0) == []


def test_lone_worker_debounce_a_buddy_flickering_away_changes_nothing() -> None:
    """The buddy is hidden now and then (predicted, still tracked): still company; a buddy
    whose track ends leaves the worker alone."""
    rule = {"name": "l", "type": "lone_worker", "zones": ["panel"], "lone_s": 3.0}
    scene = lambda t: {1: at(1.0, 3.0), 2: at(2.0, 3.0)}  # noqa: E731
    flicker = lambda t, i: i == 2 and (t % 1.0) < 0.5  # noqa: E731
    assert run(monitor(rule, lost_s=2.0), scene, 10.0, hidden=flicker) == []
    # the buddy leaves the view for good at t = 2: their track ends 2 s later (lost_s), and
    # lone_s after that the worker is alone
    mon = monitor(rule, lost_s=2.0)
    events = run(mon, scene, 2.0)
    events += run(mon, lambda t: {1: at(1.0, 3.0)}, 8.0, start=2.0)
    assert types(events) == ["lone_worker"]
    assert events[0].onset_t == pytest.approx(4.0 + DT, abs=DT + 1e-9)


def test_lone_worker_whose_track_ends_gets_an_end_marked_lost() -> None:
    rule = {"name": "l", "type": "lone_worker", "zones": ["panel"], "lone_s": 1.0}
    mon = monitor(rule, lost_s=2.0)
    events = run(mon, lambda t: {1: at(1.0, 3.0)}, 3.0)
    events += run(mon, lambda t: {}, 3.0, start=3.0)
    assert types(events) == ["lone_worker", "lone_worker_end"]
    assert events[1].lost and events[1].zone == "panel"


# --- work_position ---


def working(x: float, heading: float, y: float = 3.0, **kw) -> np.ndarray:
    """A worker at (x, y) with the right wrist pushed into the panel (x < 0.6)."""
    J = at(x, y, heading, **kw).copy()
    J[RIGHT_WRIST] = [0.4, y - 0.1, 1.2]
    return J


WORK = {
    "name": "panel_A",
    "type": "work_position",
    "zone": "front",
    "facing_deg": 180.0,
    "tolerance_deg": 30.0,
    "enter_s": 0.2,
    "exit_s": 0.4,
}


def test_work_position_held_raises_nothing() -> None:
    assert run(monitor(WORK), lambda t: {1: working(1.0, FACING_PANEL)}, 5.0) == []
    # within the tolerance
    assert run(monitor(WORK), lambda t: {1: working(1.0, FACING_PANEL + 0.4)}, 5.0) == []
    # outside the area and facing away, but no hand in the panel
    assert run(monitor(WORK), lambda t: {1: at(2.5, 3.0, 0.0)}, 5.0) == []


@pytest.mark.parametrize(
    ("x", "heading", "failed"),
    [
        (1.0, 0.0, "facing"),  # facing away from the panel
        (1.0, FACING_PANEL - 1.0, "facing"),  # 57 degrees off
        (1.9, FACING_PANEL, "position"),  # behind the work area, arm stretched
        (1.9, 0.0, "position,facing"),
    ],
)
def test_work_position_says_which_condition_failed(x: float, heading: float, failed: str) -> None:
    def scene(t: float) -> dict[int, np.ndarray]:
        return {1: working(x, heading) if t >= 1.0 else at(x, 3.0, heading)}

    events = run(monitor(WORK), scene, 4.0)
    assert types(events) == ["work_position"]
    e = events[0]
    assert e.failed == failed and e.zone == "panel" and e.joint == "right_wrist"
    assert e.onset_t == pytest.approx(1.0) and e.t == pytest.approx(1.2, abs=1e-9)
    assert e.facing_deg == pytest.approx(
        math.degrees(heading) % 360 - (360 if math.degrees(heading) % 360 > 180 else 0), abs=1.0
    )


def test_work_position_postures_and_its_end() -> None:
    rule = {**WORK, "postures": ["standing"]}

    def scene(t: float) -> dict[int, np.ndarray]:
        if t < 3.0:
            return {1: working(1.0, FACING_PANEL, bend=0.9)}  # bending: not allowed
        return {1: at(1.0, 3.0)}  # the hand out

    events = run(monitor(rule), scene, 5.0)
    assert types(events) == ["work_position", "work_position_end"]
    assert events[0].failed == "posture" and events[0].posture == "bending"
    assert events[1].t == pytest.approx(3.4, abs=1e-9)
    assert events[1].duration_s == pytest.approx(3.4, abs=1e-9)


def test_work_position_debounce_a_short_slip_is_not_an_event() -> None:
    def scene(t: float) -> dict[int, np.ndarray]:
        turned = 2.0 <= t < 2.12  # a glance away, 0.12 s < enter_s
        return {1: working(1.0, 0.0 if turned else FACING_PANEL)}

    assert run(monitor(WORK), scene, 5.0) == []


# --- immobile ---


def test_immobile_after_immobile_s_and_its_end_when_moving() -> None:
    rule = {"name": "still", "type": "immobile", "immobile_s": 10.0}
    rng = np.random.default_rng(1)
    body = b.kneeling(xy=(3.0, 3.0))

    def scene(t: float) -> dict[int, np.ndarray]:
        if t >= 15.0:
            return {1: b.standing(xy=(3.0 + 0.5 * (t - 15.0), 3.0))}
        return {1: b.noisy(body, rng, 0.01)}  # 1 cm of reconstruction noise

    events = run(monitor(rule), scene, 17.0)
    assert types(events) == ["immobile", "immobile_end"]
    assert events[0].t == pytest.approx(10.0, abs=1e-9) and events[0].posture == "crouching"
    assert events[1].onset_t == pytest.approx(15.0, abs=0.1)
    assert events[1].t == pytest.approx(events[1].onset_t + 0.2, abs=DT + 1e-9)


def test_a_worker_moving_only_the_hands_is_not_immobile() -> None:
    rule = {"name": "still", "type": "immobile", "immobile_s": 5.0}

    def scene(t: float) -> dict[int, np.ndarray]:
        J = b.standing(xy=(3.0, 3.0))
        J[RIGHT_WRIST] = J[RIGHT_SHOULDER] + [0.4, 0.3 * math.sin(2.0 * t), -0.2]
        return {1: J}

    assert run(monitor(rule), scene, 12.0) == []


def test_immobile_single_frame_glitches_do_not_restart_the_clock() -> None:
    rule = {"name": "still", "type": "immobile", "immobile_s": 5.0, "move_s": 0.2}
    body = b.lying(xy=(3.0, 3.0))

    def scene(t: float) -> dict[int, np.ndarray]:
        J = body.copy()
        if round(t * FPS) % 30 == 15:  # a joint off by 0.5 m for one frame now and then
            J[RIGHT_WRIST, 2] += 0.5
        return {1: J}

    events = run(monitor(rule), scene, 6.0)
    assert types(events) == ["immobile"] and events[0].t == pytest.approx(5.0, abs=1e-9)


# --- overreach ---


def test_overreach_debounced_with_the_wrist_and_its_height() -> None:
    rule = {"name": "over", "type": "overreach", "max_height_m": 1.9, "enter_s": 0.2, "exit_s": 0.4}

    def scene(t: float) -> dict[int, np.ndarray]:
        up = 1.0 <= t < 3.0 or 4.0 <= t < 4.12  # a 0.12 s spike later: too short
        return {1: at(3.0, 3.0, reach_left=1.0 if up else 0.0)}

    events = run(monitor(rule), scene, 6.0)
    assert types(events) == ["overreach", "overreach_end"]
    over, end = events
    assert over.onset_t == pytest.approx(1.0) and over.t == pytest.approx(1.2, abs=1e-9)
    assert over.joint == "left_wrist" and over.height_m > 1.9 and over.posture == "standing"
    assert end.onset_t == pytest.approx(3.0) and end.t == pytest.approx(3.4, abs=1e-9)


def test_every_rule_at_once_keeps_people_apart() -> None:
    """Two people, every rule: each event names the person it is about."""
    rules = [
        {"name": "d", "type": "person_down", "down_s": 2.0},
        {"name": "l", "type": "lone_worker", "zones": ["corner"], "lone_s": 2.0},
        {"name": "o", "type": "overreach", "max_height_m": 1.9},
    ]
    fallen = fall(1.0, xy=(1.0, 1.0))

    def scene(t: float) -> dict[int, np.ndarray]:
        return {1: fallen(t)[1], 7: at(8.5, 6.5, reach_right=1.0)}

    events = run(monitor(*rules), scene, 6.0)
    assert sorted((e.rule, e.person) for e in events) == [("d", 1), ("l", 7), ("o", 7)]


def test_a_fall_that_breaks_the_track_is_handed_to_the_new_id() -> None:
    """The tracker loses the body mid-fall (id 1, predicted then gone) and finds it again on
    the floor as id 2: one person_down, for id 2, timed from the fall."""
    base = fall(1.0)

    def scene(t: float) -> dict[int, np.ndarray]:
        J = base(t)[1]
        if t < 1.6:  # standing, then falling: id 1
            return {1: J}
        if t < 1.8:  # lost in the middle of the fall: predicted where it was
            return {1: base(1.56)[1]}
        return {2: J}  # on the floor: a new id

    mon = monitor({"name": "d", "type": "person_down", "down_s": 3.0}, lost_s=3.0)
    events = run(mon, scene, 8.0, hidden=lambda t, i: i == 1 and t >= 1.6)
    assert types(events) == ["person_down"] and events[0].person == 2
    assert 1.0 <= events[0].onset_t < 1.6  # the drop seen on id 1
    assert events[0].t == pytest.approx(events[0].onset_t + 3.0, abs=DT + 1e-9)

    # a new id on the floor there, but HANDOVER_S after the drop: not that fall
    def late(t: float) -> dict[int, np.ndarray]:
        return scene(t) if t < 1.8 else ({} if t < 1.6 + HANDOVER_S + 0.2 else {2: base(t)[1]})

    mon = monitor({"name": "d", "type": "person_down", "down_s": 3.0}, lost_s=3.0)
    assert run(mon, late, 8.0, hidden=lambda t, i: i == 1 and t >= 1.6) == []


def test_lying_s_raises_for_someone_found_lying() -> None:
    """Someone already lying when first seen (no fall seen): nothing by default; with lying_s,
    person_down after lying_s, and person_up when they stand."""
    lie = b.lying(xy=(3.0, 3.0))
    stand = b.standing(xy=(3.0, 3.0))
    scene = lambda t: {1: lie if t < 10.0 else stand}  # noqa: E731
    assert run(monitor({"name": "d", "type": "person_down"}), scene, 12.0) == []
    events = run(monitor({"name": "d", "type": "person_down", "lying_s": 5.0}), scene, 12.0)
    assert types(events) == ["person_down", "person_up"]
    assert events[0].onset_t == 0.0 and events[0].t == pytest.approx(5.0, abs=1e-9)
    assert events[0].speed_m_s is None
    assert events[1].t == pytest.approx(11.0, abs=1e-9)


def test_a_fall_on_a_raised_platform_is_a_fall() -> None:
    """A maintenance platform 1 m up: the fall ends near the platform's floor (its ankles')."""
    up = np.array([0.0, 0.0, 1.0])
    body = b.standing(xy=(3.0, 3.0))

    def scene(t: float) -> dict[int, np.ndarray]:
        a = min(1.0, max(0.0, (t - 1.0) / 0.7))
        return {1: b.tipped(body, 0.0, 0.5 * np.pi * a * a) + up}

    events = run(monitor({"name": "d", "type": "person_down", "down_s": 3.0}), scene, 6.0)
    assert types(events) == ["person_down"]


def test_overreach_only_near_its_zones() -> None:
    rule = {
        "name": "busbar",
        "type": "overreach",
        "max_height_m": 1.9,
        "zones": ["panel"],
        "approach_m": 0.5,
    }
    far = lambda t: {1: at(3.0, 3.0, reach_left=1.0)}  # noqa: E731
    assert run(monitor(rule), far, 2.0) == []
    near = lambda t: {1: at(1.0, 3.0, reach_left=1.0)}  # noqa: E731
    events = run(monitor(rule), near, 2.0)
    assert types(events) == ["overreach"] and events[0].zone == "panel"
