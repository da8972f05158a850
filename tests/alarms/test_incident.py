"""One incident's state machine, state by state: occur, clear, acknowledge, shelve."""

from __future__ import annotations

import json
import math

import pytest

from stereopose.alarms.incident import (
    ACKNOWLEDGED,
    ACTIVE,
    CLEARED,
    CLOSED,
    MAX_SHELVE_S,
    STATES,
    Incident,
    IncidentError,
    IncidentRecord,
)

KEY = ("zone", "panel", 3)


def in_state(state: str) -> Incident:
    """An incident raised at t = 0 (priority 2), brought to `state` by t = 2."""
    inc = Incident.raised(7, KEY, 0.0, "approach", 2, 30.0, event_id=100)
    if state in (ACKNOWLEDGED, CLOSED):
        inc.acknowledge("ann", 1.0)
    if state in (CLEARED, CLOSED):
        inc.clear(2.0)
    assert inc.state == state
    return inc


def test_a_new_incident_is_active_and_unacknowledged() -> None:
    r = in_state(ACTIVE).record()
    assert (r.state, r.occurrences, r.first_t, r.last_t, r.active_since) == (ACTIVE, 1, 0, 0, 0)
    assert (r.acked_by, r.cleared_at, r.shelved, r.first_out) == (None, None, False, False)
    assert (r.first_event, r.last_event, r.type, r.priority) == (100, 100, "approach", 2)
    assert (r.zone, r.person, r.rule, r.camera) == ("panel", 3, None, None)


OCCUR = {ACTIVE: ACTIVE, ACKNOWLEDGED: ACKNOWLEDGED, CLEARED: ACTIVE, CLOSED: ACKNOWLEDGED}
CLEAR = {
    ACTIVE: (CLEARED, True),
    ACKNOWLEDGED: (CLOSED, True),
    CLEARED: (CLEARED, False),
    CLOSED: (CLOSED, False),
}
ACK = {
    ACTIVE: (ACKNOWLEDGED, True),
    ACKNOWLEDGED: (ACKNOWLEDGED, False),
    CLEARED: (CLOSED, True),
    CLOSED: (CLOSED, False),
}


@pytest.mark.parametrize("state", STATES)
def test_an_occurrence_in_each_state(state: str) -> None:
    inc = in_state(state)
    assert inc.occur(5.0, "enter", 1, event_id=101)
    r = inc.record()
    assert r.state == OCCUR[state]
    assert (r.occurrences, r.first_t, r.last_t, r.last_type) == (2, 0.0, 5.0, "enter")
    assert (r.first_event, r.last_event) == (100, 101)
    assert r.priority == 1  # an entry is more urgent than the approach: it rises
    assert r.cleared_at is None and r.closed_at is None
    # active since it was raised, or since it came back
    assert r.active_since == (0.0 if state in (ACTIVE, ACKNOWLEDGED) else 5.0)
    inc.occur(6.0, "approach", 2)
    assert inc.record().priority == 1 and inc.record().last_event == 101  # never falls back


@pytest.mark.parametrize("state", STATES)
def test_clearing_in_each_state(state: str) -> None:
    inc = in_state(state)
    before = inc.record()
    end, changed = CLEAR[state]
    assert inc.clear(9.0) is changed
    r = inc.record()
    assert r.state == end
    if changed:
        assert r.cleared_at == 9.0 and r.active_since is None
        assert r.closed_at == (9.0 if end == CLOSED else None)
    else:
        assert r == before


@pytest.mark.parametrize("state", STATES)
def test_acknowledging_in_each_state(state: str) -> None:
    inc = in_state(state)
    before = inc.record()
    end, changed = ACK[state]
    assert inc.acknowledge("bob", 9.0) is changed
    r = inc.record()
    assert r.state == end
    if changed:
        assert (r.acked_by, r.acked_at) == ("bob", 9.0)
        assert r.closed_at == (9.0 if end == CLOSED else None)
    else:
        assert r == before  # the first acknowledgement stands


@pytest.mark.parametrize("state", [ACTIVE, ACKNOWLEDGED, CLEARED])
def test_shelving_in_each_open_state(state: str) -> None:
    inc = in_state(state)
    assert inc.shelve("ann", "  sensor work  ", 600.0, 10.0)
    r = inc.record()
    assert r.state == state and r.shelved
    assert (r.shelved_until, r.shelved_by, r.shelved_reason) == (610.0, "ann", "sensor work")
    inc.occur(20.0, "enter", 1)  # still counted while shelved
    assert inc.record().shelved and inc.record().occurrences == 2
    assert inc.shelve("bob", "longer", 1200.0, 30.0)  # shelved again: the new time
    assert inc.record().shelved_until == 1230.0 and inc.record().shelved_by == "bob"
    assert not inc.expire(1229.9) and inc.record().shelved
    assert inc.expire(1230.0)
    r = inc.record()
    assert not r.shelved and r.shelved_by is None and r.shelved_reason is None
    assert not inc.unshelve()


def test_a_closed_incident_cannot_be_shelved() -> None:
    with pytest.raises(IncidentError, match="closed: nothing to shelve"):
        in_state(CLOSED).shelve("ann", "why", 60.0, 3.0)


@pytest.mark.parametrize(
    ("reason", "duration", "message"),
    [
        ("", 60.0, "needs a reason"),
        ("   ", 60.0, "needs a reason"),
        ("ok", 0.0, "more than 0 s and at most 28800 s"),
        ("ok", -5.0, "at most 28800 s"),
        ("ok", MAX_SHELVE_S + 1, "at most 28800 s"),
        ("ok", math.nan, "at most 28800 s"),
        ("ok", math.inf, "at most 28800 s"),
        ("ok", True, "at most 28800 s"),
        ("ok", "60", "at most 28800 s"),
    ],
)
def test_shelving_is_bounded_and_needs_a_reason(reason, duration, message: str) -> None:
    inc = in_state(ACTIVE)
    with pytest.raises(IncidentError, match=message):
        inc.shelve("ann", reason, duration, 0.0)
    assert not inc.record().shelved


def test_the_bound_of_shelving_is_the_callers() -> None:
    inc = in_state(ACTIVE)
    with pytest.raises(IncidentError, match="at most 60 s"):
        inc.shelve("ann", "x", 61.0, 0.0, max_shelve_s=60.0)
    assert inc.shelve("ann", "x", MAX_SHELVE_S, 0.0)  # the bound itself is allowed


def test_a_long_reason_is_cut() -> None:
    inc = in_state(ACTIVE)
    inc.shelve("ann", "x" * 10_000, 60.0, 0.0)
    assert len(inc.record().shelved_reason or "") == 500


@pytest.mark.parametrize("state", STATES)
def test_records_round_trip_through_json(state: str) -> None:
    inc = in_state(state)
    if state != CLOSED:
        inc.shelve("ann", "maintenance", 60.0, 3.0)
    rec = inc.record()
    d = json.loads(json.dumps(rec.to_dict()))
    assert d["key"] == ["zone", "panel", 3] and d["zone"] == "panel" and d["person"] == 3
    assert d["shelved"] is (state != CLOSED)
    assert IncidentRecord.from_dict(d) == rec


@pytest.mark.parametrize(
    ("change", "message"),
    [({"state": "open"}, "unknown state 'open'"), ({"key": None}, "not an incident record")],
)
def test_bad_records_are_incident_errors(change, message: str) -> None:
    d = in_state(ACTIVE).record().to_dict() | change
    with pytest.raises(IncidentError, match=message):
        IncidentRecord.from_dict(d)
    d = in_state(ACTIVE).record().to_dict()
    del d["id"]
    with pytest.raises(IncidentError, match="not an incident record"):
        IncidentRecord.from_dict(d)
