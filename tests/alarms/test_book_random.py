"""Property: over random event sequences and operators' acts, every alarm event belongs to
exactly one incident, of its own hazard, and every incident's state is always valid."""

from __future__ import annotations

import numpy as np
import pytest
from alarm_events import camera, rule, service, zone

from stereopose.alarms import (
    ACKNOWLEDGED,
    ACTIVE,
    CLEARED,
    CLOSED,
    STATES,
    AlarmSettings,
    IncidentBook,
    IncidentError,
    Tuning,
    hazard_key,
    raises,
)

ZONES = (("panel", "energized"), ("door", "restricted"), ("bench", "work_area"))
ZONE_TYPES = ("enter", "exit", "approach", "dwell", "left_work_area")
RULES = (("man_down", "person_down", "person_up"), ("two", "lone_worker", "lone_worker_end"))
CAMERA_TYPES = ("camera_down", "camera_up", "calibration_drift", "calibration_recovered")


def random_event(rng: np.random.Generator, t: float):
    u = rng.random()
    person = int(rng.integers(1, 4))
    if u < 0.6:
        name, kind = ZONES[int(rng.integers(len(ZONES)))]
        return zone(t, str(rng.choice(ZONE_TYPES)), person, name, kind)
    if u < 0.8:
        name, on, off = RULES[int(rng.integers(len(RULES)))]
        return rule(t, on if rng.random() < 0.5 else off, person, name)
    if u < 0.95:
        return camera(t, str(rng.choice(CAMERA_TYPES)), f"cam{int(rng.integers(2))}")
    return service(t, "service_stalled" if rng.random() < 0.5 else "service_resumed")


def check_record(r, now: float) -> None:
    assert r.state in STATES and 1 <= r.priority <= 4
    assert r.active == (r.state in (ACTIVE, ACKNOWLEDGED))
    assert (r.cleared_at is None) == r.active
    assert (r.active_since is not None) == r.active
    assert (r.acked_by is not None) == (r.state in (ACKNOWLEDGED, CLOSED))
    assert (r.closed_at is not None) == (r.state == CLOSED)
    assert r.occurrences >= 1 and r.first_t <= r.last_t
    assert r.shelved_until is None or r.shelved_until > now


@pytest.mark.parametrize("seed", range(8))
@pytest.mark.parametrize("with_holding", [False, True])
def test_random_sequences_keep_the_book_consistent(seed: int, with_holding: bool) -> None:
    rng = np.random.default_rng(seed)
    rearm = {name: Tuning(None, float(rng.choice([0.0, 5.0, 30.0]))) for name, _ in ZONES}
    book = IncidentBook(AlarmSettings(zones=rearm), max_incidents=40, approach_clear_s=8.0)
    assigned: dict[int, int] = {}  # incident id -> events given to it
    latest = {}  # incident id -> its latest record seen in a change
    raised = notified = born_shelved = 0
    t = 0.0
    for _ in range(1500):
        t += float(rng.exponential(1.5))
        events = [random_event(rng, t) for _ in range(int(rng.integers(0, 4)))]
        holding = None
        if with_holding:
            holding = {(n, p) for n, _ in ZONES for p in (1, 2, 3) if rng.random() < 0.3}
        up = book.update(events, t, holding=holding)
        assert len(up.incidents) == len(events)
        for e, i in zip(events, up.incidents, strict=True):
            assert (i is not None) == raises(e)  # an alarm or warning: exactly one incident
            if i is not None:
                assigned[i] = assigned.get(i, 0) + 1
                rec = book.get(i) if i in book else latest[i]
                assert rec.key == hazard_key(e)
        for c in up.changes:
            latest[c.incident.id] = c.incident
            raised += c.what == "raised"
            notified += c.notify
            born_shelved += c.what == "raised" and c.incident.shelved
            assert c.notify == (c.what == "raised" and not c.incident.shelved)
            if c.what == "raised":
                assert c.incident.id > max((k for k in latest if k != c.incident.id), default=0)
        # an operator now and then
        if len(book) and rng.random() < 0.3:
            target = int(rng.choice([r.id for r in book.incidents()]))
            act = rng.random()
            try:
                if act < 0.5:
                    changes = book.acknowledge(target, "ann", t)
                elif act < 0.8:
                    changes = book.shelve(target, "bob", "check", float(rng.uniform(1, 60)), t)
                else:
                    changes = book.unshelve(target, "bob", t)
            except IncidentError as err:
                assert "closed" in str(err)  # shelving a closed one is the only refusal
                changes = []
            for c in changes:
                latest[c.incident.id] = c.incident
        records = book.incidents()
        assert len(records) <= 40
        active_keys = [r.key for r in records if r.active]
        assert len(active_keys) == len(set(active_keys))  # one active incident per hazard
        for r in records:
            check_record(r, t)
    # a notification for each new incident only, unless its hazard is shelved
    assert raised == len(assigned) and notified == raised - born_shelved > 0
    for i, n in assigned.items():
        assert latest[i].occurrences == n  # every event given to it counted, none other
    assert sum(assigned.values()) > len(assigned)  # occurrences did happen
    assert any(r.state == CLEARED for r in latest.values())
