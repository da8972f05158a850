"""Postures of synthetic skeletons: each posture and flag from simple geometry, bodies with
missing joints, and the tracker's motion and standing height."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import bodies as b
from stereopose.behaviour import POSTURES, PostureSettings, PostureTracker, classify
from stereopose.skeleton import (
    LEFT_ANKLE,
    LEFT_HIP,
    LEFT_KNEE,
    LEFT_SHOULDER,
    LEFT_WRIST,
    NUM_JOINTS,
    RIGHT_ANKLE,
    RIGHT_HIP,
    RIGHT_KNEE,
    RIGHT_SHOULDER,
    RIGHT_WRIST,
)

LOWER = [LEFT_HIP, RIGHT_HIP, LEFT_KNEE, RIGHT_KNEE, LEFT_ANKLE, RIGHT_ANKLE]
UPPER = [j for j in range(NUM_JOINTS) if j not in LOWER]


@pytest.mark.parametrize(
    ("body", "expected"),
    [
        (b.standing(), "standing"),
        (b.standing(1.55, (3.0, -1.0), 2.0), "standing"),
        (b.standing(2.0, heading=-1.0), "standing"),
        (b.standing(bend=0.9), "bending"),
        (b.standing(bend=1.4), "bending"),  # into a low panel: hips stay high
        (b.kneeling(), "crouching"),
        (b.kneeling(one_knee=True), "crouching"),
        (b.kneeling(lean=0.6), "crouching"),
        (b.kneeling(lean=1.3), "crouching"),  # kneeling bent deep forward: not lying
        (b.kneeling(1.5, lean=1.4), "crouching"),
        (b.squatting(), "crouching"),
        (b.squatting(1.5, heading=2.5), "crouching"),
        (b.sitting_chair(), "crouching"),
        (b.sitting_floor(), "crouching"),
        (b.lying(), "lying"),
        (b.lying(heading=1.2, xy=(4.0, 2.0)), "lying"),
        (b.lying(sideways=True), "lying"),
        (b.lying(2.0, sideways=True), "lying"),  # a tall body on its side
    ],
)
def test_posture_of_synthetic_bodies(body: np.ndarray, expected: str) -> None:
    assert expected in POSTURES
    assert classify(body).posture == expected


def test_the_geometry_behind_the_postures() -> None:
    stand = classify(b.standing())
    assert stand.torso_deg == pytest.approx(0.0, abs=1e-6)
    assert stand.hip_height_m == pytest.approx(0.525 * 1.75, abs=0.01)
    assert stand.knee_deg == pytest.approx(180.0, abs=1.0)
    kneel = classify(b.kneeling())
    assert kneel.knee_deg == pytest.approx(90.0, abs=1.0)
    assert kneel.hip_height_m < 0.72 * 0.9
    bend = classify(b.standing(bend=0.9))
    assert bend.torso_deg == pytest.approx(math.degrees(0.9), abs=1.0)
    lie = classify(b.lying())
    assert lie.torso_deg == pytest.approx(90.0, abs=1.0) and lie.top_m < 0.3


def test_the_thresholds_decide() -> None:
    """A posture moves across a threshold when the threshold moves."""
    body = b.standing(bend=0.9)  # torso about 52 degrees from vertical
    assert classify(body, settings=PostureSettings(bend_deg=50.0)).posture == "bending"
    assert classify(body, settings=PostureSettings(bend_deg=55.0)).posture == "standing"
    kneel = b.kneeling()  # hips at 0.49 m
    assert classify(kneel, standing_hip_m=0.9).posture == "crouching"
    assert classify(kneel, standing_hip_m=0.65).posture == "standing"
    moving = classify(b.standing(), speed_m_s=1.2)
    assert moving.posture == "walking"
    assert classify(b.standing(), speed_m_s=0.1).posture == "standing"


def test_flags_arms_raised_and_reaching() -> None:
    assert classify(b.standing()).flags == ()
    raised = classify(b.standing(reach_right=1.0))
    assert raised.flags == ("arms_raised",) and raised.wrist_m > 1.8
    # a straight arm held forward at shoulder height
    J = b.standing()
    J[RIGHT_WRIST] = J[RIGHT_SHOULDER] + [0.6, 0.0, 0.0]
    reach = classify(J)
    assert "reaching" in reach.flags and reach.reach_m == pytest.approx(0.6, abs=0.01)
    # walking arm swing is not reaching
    swing = classify(b.standing(gait=1.0, phase=1.5))
    assert swing.flags == ()
    # without a head, a wrist well above the shoulders is raised
    J = b.standing(reach_left=1.0)
    J[:5] = np.nan
    assert "arms_raised" in classify(J).flags
    # a lying body has no flags (its wrists are above its head's top by nothing)
    assert classify(b.lying()).flags == ()


def test_lying_half_outside_the_view() -> None:
    """Only the legs, or only the upper body, of a lying person: still lying."""
    body = b.lying(heading=0.7, xy=(2.0, 1.0))
    legs_only = body.copy()
    legs_only[UPPER] = np.nan
    assert classify(legs_only).posture == "lying"
    upper_only = body.copy()
    upper_only[LOWER] = np.nan
    assert classify(upper_only).posture == "lying"
    one_side = body.copy()
    one_side[[LEFT_SHOULDER, LEFT_HIP, LEFT_WRIST, LEFT_KNEE, LEFT_ANKLE, RIGHT_SHOULDER]] = np.nan
    assert classify(one_side).posture == "lying"
    # the same legs standing tell nothing (no trunk): unknown, never lying
    stand_legs = b.standing()
    stand_legs[[*UPPER, LEFT_HIP, RIGHT_HIP]] = np.nan
    assert classify(stand_legs).posture == "unknown"


def test_noisy_bodies_with_missing_joints_keep_their_posture() -> None:
    """2 cm of noise and a fifth of the joints missing (as where few cameras see a body)."""
    rng = np.random.default_rng(4)
    cases = [
        (b.standing, "standing"),
        (b.kneeling, "crouching"),
        (b.lying, "lying"),
        (lambda: b.lying(sideways=True), "lying"),
        (lambda: b.standing(bend=1.1), "bending"),
        (b.squatting, "crouching"),
    ]
    for make, expected in cases:
        got = [classify(b.noisy(make(), rng, 0.02, missing=0.2)).posture for _ in range(50)]
        assert sum(g == expected for g in got) >= 45, (expected, got)
        # lying is never mistaken for another posture, nor another for lying
        assert all((g == "lying") == (expected == "lying") for g in got if g != "unknown")


def test_too_few_joints_is_unknown_and_shapes_are_checked() -> None:
    J = np.full((NUM_JOINTS, 3), np.nan)
    assert classify(J).posture == "unknown"
    J[LEFT_WRIST] = J[RIGHT_WRIST] = [0.0, 0.0, 1.0]
    assert classify(J).posture == "unknown"
    with pytest.raises(ValueError, match=r"\(17, 3\)"):
        classify(np.zeros((16, 3)))


def _walk(tracker: PostureTracker, fps: float, seconds: float, speed: float, pid: int = 1):
    out = []
    for k in range(int(seconds * fps)):
        t = k / fps
        J = b.standing(xy=(speed * t, 0.0), gait=1.0 if speed else 0.0, phase=7.0 * t)
        out.append(tracker.update(t, b.people(k, {pid: J}, t))[pid])
    return out


def test_tracker_walking_against_standing() -> None:
    fps = 25.0
    walked = _walk(PostureTracker(fps), fps, 3.0, speed=1.2)
    assert math.isnan(walked[0].speed_m_s)  # no history yet
    assert {p.posture for p in walked[int(fps) :]} == {"walking"}
    assert walked[-1].speed_m_s == pytest.approx(1.2, abs=0.05)
    stood = _walk(PostureTracker(fps), fps, 3.0, speed=0.0)
    assert {p.posture for p in stood} == {"standing"}


def test_tracker_learns_a_persons_standing_height() -> None:
    """A tall worker's half crouch is crouching once their standing height is known; before,
    against the default 0.9 m, it is not."""
    fps = 25.0
    tall = 2.05
    stand = b.standing(tall)
    own = stand[[LEFT_HIP, RIGHT_HIP], 2].mean() - (stand[LEFT_ANKLE, 2] - 0.07)  # above feet
    half = b.squatting(tall, lean=0.2, hip_z=0.72)  # a half squat, knees bent
    assert classify(half).posture == "standing"  # against the default 0.9 m
    tracker = PostureTracker(fps)
    for k in range(50):
        tracker.update(k / fps, b.people(k, {5: stand}, k / fps))
    assert tracker.standing_hip(5) == pytest.approx(own, abs=0.01)
    assert tracker.update(2.0, b.people(50, {5: half}, 2.0))[5].posture == "crouching"
    # crouching for long does not lower the standing height it is compared with
    for k in range(51, 800):
        tracker.update(k / fps, b.people(k, {5: half}, k / fps))
    assert tracker.standing_hip(5) == pytest.approx(own, abs=0.01)


def test_standing_on_a_lower_floor_or_a_step_is_not_crouching() -> None:
    """Hips are measured above the feet: a worker whose floor is 0.3 m below the world's
    z = 0, or who stands on a 0.5 m step, is standing; kneeling there is crouching."""
    for dz in (-0.3, 0.5):
        shift = np.array([0.0, 0.0, dz])
        assert classify(b.standing() + shift).posture == "standing"
        assert classify(b.kneeling() + shift).posture == "crouching"
        assert classify(b.lying() + shift).posture == "lying"  # on a platform too
    # legs hidden behind a cabinet: head and shoulders alone are high, not lying
    upper = b.standing()
    upper[[LEFT_HIP, RIGHT_HIP, LEFT_KNEE, RIGHT_KNEE, LEFT_ANKLE, RIGHT_ANKLE]] = np.nan
    upper[[7, 8, 9, 10]] = np.nan
    assert classify(upper).posture != "lying"
    # a short worker (hips 0.6 m above the floor) is learnt as such
    short = b.standing(1.2)
    tracker = PostureTracker(25.0)
    got = [tracker.update(k / 25, b.people(k, {1: short}, k / 25))[1].posture for k in range(30)]
    assert set(got) == {"standing"}
    assert tracker.standing_hip(1) == pytest.approx(0.525 * 1.2 - 0.045 * 1.2 + 0.07, abs=0.01)


def test_tracker_drop_speed_and_forgetting() -> None:
    fps = 25.0
    tracker = PostureTracker(fps, lost_s=1.0)
    seq = fall_sequence(fps)
    drops = [
        tracker.update(k / fps, b.people(k, {3: J}, k / fps))[3].drop_m_s for k, J in enumerate(seq)
    ]
    assert np.nanmax(drops) > 1.5  # a fall: the hips drop fast
    # predicted (unseen) frames keep the last posture
    last = tracker.update(len(seq) / fps, b.people(len(seq), {3: b.standing()}, None, {3: True}))
    assert last[3].posture == "lying"
    tracker.update(100.0, b.people(9999, {}, 100.0))
    assert 3 not in tracker.people  # the track ended: forgotten


def fall_sequence(
    fps: float,
    stand_s: float = 1.0,
    fall_s: float = 0.7,
    lie_s: float = 1.0,
    heading: float = 0.0,
    xy=(1.0, 1.0),
) -> list[np.ndarray]:
    """Standing, then rotating to the floor about the ankles (accelerating), then lying."""
    body = b.standing(xy=xy, heading=heading)
    frames = [body] * int(stand_s * fps)
    n = int(fall_s * fps)
    for k in range(1, n + 1):
        frames.append(b.tipped(body, heading, 0.5 * np.pi * (k / n) ** 2))
    frames += [b.tipped(body, heading, 0.5 * np.pi)] * int(lie_s * fps)
    return frames


BUILDERS = {
    "standing": lambda h, xy, a: b.standing(h, xy, a),
    "bending": lambda h, xy, a: b.standing(h, xy, a, bend=1.0),
    "crouching": lambda h, xy, a: b.kneeling(h, xy, a),
    "lying": lambda h, xy, a: b.lying(h, xy, a, sideways=xy[0] > 0),
}


@given(
    kind=st.sampled_from(sorted(BUILDERS)),
    height=st.floats(1.5, 2.0),
    x=st.floats(-50.0, 50.0),
    y=st.floats(-50.0, 50.0),
    heading=st.floats(-math.pi, math.pi),
)
@settings(max_examples=150, deadline=None)
def test_posture_does_not_depend_on_where_or_which_way(kind, height, x, y, heading) -> None:
    """The same body anywhere on the floor, facing any way, of any adult height."""
    assert classify(BUILDERS[kind](height, (x, y), heading)).posture == kind
