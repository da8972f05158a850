"""JSON records of People3D and Event: the contracts, and round trips through them."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from stereopose.io.records import (
    EVENT_COLUMNS,
    event_from_record,
    event_record,
    event_row,
    frame_record,
    parse_frame_record,
    people3d_from_record,
)
from stereopose.types import Event, People3D


def random_people(rng: np.random.Generator, frame: int, P: int, C: int = 3) -> People3D:
    J = rng.uniform(-3, 3, (P, 17, 3))
    gone = rng.random((P, 17)) < 0.2
    J[gone] = np.nan
    conf = np.where(gone, 0.0, rng.uniform(0.1, 1.0, (P, 17)))
    err = np.where(gone, np.nan, rng.uniform(0, 9, (P, 17)))
    return People3D(
        frame,
        J,
        conf,
        rng.permutation(50)[:P],
        err,
        np.where(gone, 0, rng.integers(1, C + 1, (P, 17))),
        rng.integers(-1, 4, (P, C)),
        predicted=rng.random(P) < 0.3,
        velocity=np.where(rng.random((P, 1)) < 0.2, np.nan, rng.normal(0, 1, (P, 2))),
    )


@pytest.mark.parametrize("seed", range(5))
def test_people3d_round_trip(seed: int) -> None:
    rng = np.random.default_rng(seed)
    people = random_people(rng, frame=int(rng.integers(0, 10_000)), P=int(rng.integers(0, 5)))
    text = json.dumps(frame_record(people, 25.0))  # through the text of a line, as in a file
    frame, t, parsed = parse_frame_record(json.loads(text))
    back = people3d_from_record(frame, parsed, num_cameras=3)
    assert frame == people.frame and t == pytest.approx(people.frame / 25.0)
    assert len(back) == len(people)
    np.testing.assert_allclose(back.joints, people.joints, atol=5e-5)  # 0.1 mm
    np.testing.assert_array_equal(np.isnan(back.joints), np.isnan(people.joints))
    np.testing.assert_allclose(back.conf, people.conf, atol=5e-4)
    np.testing.assert_array_equal(back.ids, people.ids)
    np.testing.assert_array_equal(back.views, people.views)
    np.testing.assert_array_equal(back.predicted, people.predicted)
    np.testing.assert_allclose(back.velocity, people.velocity, atol=5e-4)
    np.testing.assert_array_equal(np.isnan(back.velocity), np.isnan(people.velocity))
    # not stored: per-joint errors and the detections used
    assert np.isnan(back.reprojection_px).all() and (back.detections == -1).all()
    assert back.detections.shape == (len(people), 3)
    # a second trip changes nothing that the record stores
    stored = ("id", "joints", "conf", "velocity", "predicted", "views")
    again = frame_record(back, 25.0)["people"]
    first = frame_record(people, 25.0)["people"]
    assert [{k: p[k] for k in stored} for p in again] == [{k: p[k] for k in stored} for p in first]


def test_frame_record_fields() -> None:
    people = random_people(np.random.default_rng(9), frame=50, P=2)
    rec = frame_record(people, 25.0)
    assert rec["frame"] == 50 and rec["t"] == 2.0
    p = rec["people"][0]
    assert set(p) == {
        "id",
        "joints",
        "conf",
        "position",
        "velocity",
        "speed",
        "heading_deg",
        "predicted",
        "views",
        "reprojection_px",
    }
    assert len(p["joints"]) == 17 and all(j is None or len(j) == 3 for j in p["joints"])
    errs = people.reprojection_px[0]
    assert p["reprojection_px"] == pytest.approx(np.nanmean(errs), abs=0.005)


def test_minimal_frame_record_reads() -> None:
    """Only frame, people[].id and people[].joints are required."""
    frame, t, people = parse_frame_record(
        {"frame": 3, "people": [{"id": 7, "joints": [None] * 16 + [[1.0, 2.0, 3.0]]}]}
    )
    assert (frame, t) == (3, None)
    back = people3d_from_record(frame, people)
    assert back.ids.tolist() == [7] and back.conf[0, 16] == 1.0 and back.conf[0, 0] == 0.0
    assert not back.predicted[0] and np.isnan(back.velocity).all()
    for bad in (
        {"people": []},
        {"frame": 1, "people": [{"joints": [None] * 17}]},
        {"frame": 1, "people": [{"id": 1, "joints": [None] * 3}]},
    ):
        with pytest.raises((KeyError, ValueError, TypeError)):
            parse_frame_record(bad)


EVENTS = [
    Event(
        t=2.12,
        frame=53,
        person=3,
        zone="work_area_1",
        kind="work_area",
        type="enter",
        onset_t=2.04,
        joint="right_wrist",
        position=(1.2346, -0.5),
    ),
    Event(
        t=4.0,
        frame=100,
        person=1,
        zone="panel",
        kind="energized",
        type="approach",
        onset_t=3.9,
        joint="left_wrist",
        distance_m=0.3125,
        position=(0.5, 0.25),
    ),
    Event(
        t=9.5,
        frame=237,
        person=2,
        zone="bench",
        kind="work_area",
        type="exit",
        onset_t=9.3,
        duration_s=4.25,
        allowed=True,
        lost=True,
    ),
]


@pytest.mark.parametrize("event", EVENTS, ids=lambda e: e.type)
def test_event_round_trip(event: Event) -> None:
    rec = json.loads(json.dumps(event_record(event)))
    assert event_from_record(rec) == event
    # the SQLite row holds the same event
    row = dict(zip(EVENT_COLUMNS, event_row(event, run=4), strict=True))
    assert row["run"] == 4 and event_from_record(row) == event


def test_event_record_is_the_contract() -> None:
    rec = event_record(dataclasses.replace(EVENTS[0], position=(1.23456, -0.5)))
    assert rec == {
        "t": 2.12,
        "frame": 53,
        "person": 3,
        "zone": "work_area_1",
        "kind": "work_area",
        "type": "enter",
        "onset_t": 2.04,
        "joint": "right_wrist",
        "position": [1.2346, -0.5],
        "incident": None,
        "priority": None,
    }
    # every line carries its incident and priority (null: none), and reads back
    stamped = dataclasses.replace(EVENTS[0], incident=12, priority=1)
    assert event_record(stamped)["incident"] == 12 and event_record(stamped)["priority"] == 1
    assert event_from_record(event_record(stamped)) == stamped
    assert event_record(EVENTS[2])["allowed"] is True and "joint" not in event_record(EVENTS[2])
    assert event_record(EVENTS[2])["position"] is None
    assert not hasattr(EVENTS[0], "as_dict")  # io.records is the one serialisation
