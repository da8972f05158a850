"""The incident book step by step: one incident per hazard, re-arm, clearing, notifications,
first-out, shelving through the book, bounds and a restart."""

from __future__ import annotations

import itertools

import pytest
from alarm_events import camera, rule, service, zone

from stereopose.alarms import (
    ACKNOWLEDGED,
    ACTIVE,
    CLEARED,
    CLOSED,
    AlarmSettings,
    IncidentBook,
    IncidentError,
    Tuning,
    UnknownIncidentError,
)

EPS = 1e-6


def step(book: IncidentBook, events, now: float | None = None, **kw):
    now = max((e.t for e in events), default=0.0) if now is None else now
    return book.update(list(events), now, **kw)


def whats(update) -> list[tuple[str, str | None, str]]:
    return [(c.what, c.before, c.incident.state) for c in update.changes]


def test_an_approach_that_becomes_an_entry_is_one_incident_that_rises() -> None:
    book = IncidentBook()
    up = step(book, [zone(0.0, "approach")])
    assert up.incidents == (1,) and whats(up) == [("raised", None, ACTIVE)]
    assert [c.incident.priority for c in up.notifications] == [2]
    up = step(book, [zone(0.5, "enter")])
    assert up.incidents == (1,) and up.notifications == ()
    assert whats(up) == [("occurrence", ACTIVE, ACTIVE)]
    r = book.get(1)
    assert (r.occurrences, r.priority, r.type, r.last_type) == (2, 1, "approach", "enter")
    assert r.worst_type == "enter"  # its line names the entry, not the approach
    up = step(book, [zone(1.0, "approach")])  # back at the margin: the worst stays the entry
    r = book.get(1)
    assert (r.last_type, r.worst_type, r.priority) == ("approach", "enter", 1)
    assert type(r).from_dict(r.to_dict()).worst_type == "enter"
    old = r.to_dict()
    del old["worst_type"]  # a record an earlier version stored
    assert type(r).from_dict(old).worst_type == ""


def test_a_repeated_reach_is_one_incident_with_a_count_and_one_notification() -> None:
    book = IncidentBook()
    events = []
    for k in range(8):  # in and out of the panel every 3 s, back at the margin each time
        t = 3.0 * k
        events += [zone(t, "approach"), zone(t + 0.5, "enter"), zone(t + 2.0, "exit")]
    ups = [step(book, [e]) for e in events]
    assert {i for u in ups for i in u.incidents if i is not None} == {1}
    assert sum(len(u.notifications) for u in ups) == 1
    assert book.get(1).occurrences == 16 and book.get(1).last_t == 21.5
    # each exit clears it, each return makes it active again: the changes say so
    assert [w for u in ups[:4] for w in whats(u)] == [
        ("raised", None, ACTIVE),
        ("occurrence", ACTIVE, ACTIVE),
        ("cleared", ACTIVE, CLEARED),
        ("occurrence", CLEARED, ACTIVE),
    ]


@pytest.mark.parametrize("acked", [False, True])
@pytest.mark.parametrize(("gap", "same"), [(30.0 - EPS, True), (30.0 + EPS, False)])
def test_the_rearm_window(acked: bool, gap: float, same: bool) -> None:
    book = IncidentBook()
    step(book, [zone(0.0, "enter")])
    step(book, [zone(5.0, "exit")])
    if acked:
        assert book.acknowledge(1, "ann", 6.0)[0].incident.state == CLOSED
    up = step(book, [zone(5.0 + gap, "enter")])
    assert up.incidents == ((1,) if same else (2,))
    assert len(up.notifications) == (0 if same else 1)
    if same:
        assert book.get(1).state == (ACKNOWLEDGED if acked else ACTIVE)
    else:
        assert book.get(2).state == ACTIVE and book.get(2).occurrences == 1
        # the old one: forgotten once closed and re-armed; still waiting for an ack if not
        assert (1 in book) is not acked


def test_rearm_per_zone_and_rule_from_the_settings() -> None:
    settings = AlarmSettings(
        zones={"panel": Tuning(None, 2.0)}, rules={"man_down": Tuning(1, 100.0)}
    )
    book = IncidentBook(settings)
    step(book, [zone(0.0, "enter"), rule(0.0, "person_down")])
    step(book, [zone(1.0, "exit"), rule(1.0, "person_up")])
    up = step(book, [zone(3.5, "enter"), rule(90.0, "person_down")])
    assert up.incidents == (3, 2) and len(up.notifications) == 1  # zone: a new one


def test_a_zone_priority_replaces_the_defaults() -> None:
    book = IncidentBook(AlarmSettings(zones={"panel": Tuning(3, 30.0)}))
    step(book, [zone(0.0, "approach"), zone(0.5, "enter")])
    assert book.get(1).priority == 3


def test_info_events_have_no_incident_and_warnings_do() -> None:
    book = IncidentBook()
    events = [
        zone(0.0, "enter", kind="work_area"),
        zone(0.1, "exit", kind="work_area"),
        zone(0.2, "enter", kind="restricted", zone_="door"),
        zone(0.3, "dwell", kind="work_area", zone_="bench"),
        camera(0.4, "camera_up"),
        rule(0.5, "person_up"),
    ]
    up = step(book, events)
    assert up.incidents == (None, None, 1, 2, None, None)
    assert [c.incident.priority for c in up.notifications] == [3, 3]


@pytest.mark.parametrize(
    ("raise_", "end"),
    [
        (rule(0.0, "person_down"), rule(4.0, "person_up")),
        (rule(0.0, "lone_worker", name="two"), rule(4.0, "lone_worker_end", name="two")),
        (rule(0.0, "overreach", name="up"), rule(4.0, "overreach_end", name="up")),
        (camera(0.0, "camera_down"), camera(4.0, "camera_up")),
        (camera(0.0, "calibration_drift"), camera(4.0, "calibration_recovered")),
        (service(0.0, "service_stalled"), service(4.0, "service_resumed")),
        (zone(0.0, "enter", kind="restricted"), zone(4.0, "exit", kind="restricted")),
        (zone(0.0, "left_work_area", kind="work_area"), zone(4.0, "enter", kind="work_area")),
    ],
)
def test_each_hazard_clears_at_its_end_event(raise_, end) -> None:
    book = IncidentBook()
    step(book, [raise_])
    up = step(book, [end])
    assert up.incidents == (None,) and whats(up) == [("cleared", ACTIVE, CLEARED)]
    assert book.get(1).cleared_at == 4.0


def test_a_camera_back_does_not_clear_its_calibration() -> None:
    book = IncidentBook()
    step(book, [camera(0.0, "calibration_drift"), camera(1.0, "camera_down")])
    step(book, [camera(2.0, "camera_up")])
    assert [(r.key, r.state) for r in book.incidents()] == [
        (("calibration", "cam1"), ACTIVE),
        (("camera", "cam1"), CLEARED),
    ]


def test_people_zones_and_rules_are_separate_hazards() -> None:
    book = IncidentBook()
    events = [
        zone(0.0, "enter", 1),
        zone(0.0, "enter", 2),
        zone(0.0, "enter", 1, "b"),
        rule(0.0, "person_down", 1),
        rule(0.0, "person_down", 1, "other"),
    ]
    up = step(book, events)
    assert up.incidents == (1, 2, 3, 4, 5) and len(up.notifications) == 5


def test_an_approach_without_holding_clears_after_its_quiet_time() -> None:
    book = IncidentBook(approach_clear_s=10.0)
    step(book, [zone(0.0, "approach")])
    step(book, [zone(6.0, "approach")])  # a later approach moves the time on
    assert step(book, [], 15.9).changes == ()
    up = step(book, [], 16.0)
    assert whats(up) == [("cleared", ACTIVE, CLEARED)] and book.get(1).cleared_at == 16.0
    # inside: only its exit clears it
    step(book, [zone(20.0, "enter")])
    assert step(book, [], 100.0).changes == () and book.get(1).active


def test_holding_keeps_a_person_at_the_margin_active_and_clears_one_gone() -> None:
    book = IncidentBook()
    held = {("panel", 1)}
    step(book, [zone(0.0, "enter")], holding=held)
    # out of the zone but still within its margin: not returned to normal
    up = step(book, [zone(1.0, "exit")], holding=held)
    assert up.changes == () and book.get(1).state == ACTIVE
    assert step(book, [], 500.0, holding=held).changes == ()  # no time-out while held
    up = step(book, [], 501.0, holding=set())
    assert whats(up) == [("cleared", ACTIVE, CLEARED)] and book.get(1).cleared_at == 501.0


def test_first_out_marks_the_first_of_a_burst_only() -> None:
    book = IncidentBook(first_out_s=10.0)
    assert whats(step(book, [zone(0.0, "enter")])) == [("raised", None, ACTIVE)]
    assert not book.get(1).first_out  # alone, it is no first of anything
    up = step(book, [camera(4.0, "camera_down")])
    assert [c.what for c in up.changes] == ["raised", "first_out"]
    assert up.changes[1].incident.id == 1 and book.get(1).first_out
    up = step(book, [rule(9.0, "person_down")])
    assert [c.what for c in up.changes] == ["raised"]
    up = step(book, [service(30.0, "service_stalled"), zone(31.0, "enter", 5)])
    assert [c.what for c in up.changes] == ["raised", "raised", "first_out"]
    assert [r.id for r in book.incidents() if r.first_out] == [1, 4]


def test_operators_acts_through_the_book() -> None:
    book = IncidentBook(max_shelve_s=3600.0)
    step(book, [zone(0.0, "enter")])
    (c,) = book.shelve(1, "ann", "panel isolated", 600.0, 1.0)
    assert (c.what, c.by, c.incident.shelved_until) == ("shelved", "ann", 601.0)
    with pytest.raises(IncidentError, match="at most 3600 s"):
        book.shelve(1, "ann", "x", 3601.0, 1.0)
    # shelved: occurrences still counted and recorded
    up = step(book, [zone(5.0, "exit"), zone(6.0, "enter")])
    assert up.incidents == (None, 1) and book.get(1).occurrences == 2 and book.get(1).shelved
    assert step(book, [], 600.9).changes == ()
    up = step(book, [], 601.0)
    assert whats(up) == [("unshelved", ACTIVE, ACTIVE)] and not book.get(1).shelved
    assert up.changes[0].by is None  # the time ran out
    (c,) = book.acknowledge(1, "bob", 602.0)
    assert (c.what, c.before, c.incident.state, c.by) == (
        "acknowledged",
        ACTIVE,
        ACKNOWLEDGED,
        "bob",
    )
    assert book.acknowledge(1, "eve", 603.0) == []
    book.shelve(1, "ann", "again", 60.0, 604.0)
    assert [c.what for c in book.unshelve(1, "ann", 605.0)] == ["unshelved"]
    assert book.unshelve(1, "ann", 606.0) == []
    assert step(book, [], 700.0).changes == ()  # the old shelving time is stale
    for act in (
        lambda: book.acknowledge(9, "a", 0),
        lambda: book.shelve(9, "a", "r", 1, 0),
        lambda: book.unshelve(9, "a", 0),
        lambda: book.get(9),
    ):
        with pytest.raises(UnknownIncidentError, match="no open incident 9"):
            act()


def test_ids_come_from_the_callers_allocator_and_event_ids_are_kept() -> None:
    book = IncidentBook(next_id=itertools.count(500).__next__)
    up = step(
        book,
        [zone(0.0, "enter"), zone(0.1, "dwell"), camera(0.2, "camera_down")],
        event_ids=[11, 12, 13],
    )
    assert up.incidents == (500, 500, 501)
    assert (book.get(500).first_event, book.get(500).last_event) == (11, 12)
    with pytest.raises(ValueError, match="2 event ids for 1 events"):
        step(book, [zone(1.0, "exit")], event_ids=[1, 2])


def test_closed_incidents_are_forgotten_and_memory_stays_bounded() -> None:
    """A day of a worker reaching into a panel every 2 minutes, each acknowledged."""
    book = IncidentBook()
    seen = 0
    for k in range(720):
        t = 120.0 * k
        up = step(book, [zone(t, "approach"), zone(t + 1, "enter")])
        seen += len(up.notifications)
        step(book, [zone(t + 5, "exit")])
        book.acknowledge(up.incidents[0], "ann", t + 6)
        step(book, [], t + 60)
        assert len(book) <= 1
        assert max(len(book._forget), len(book._approach), len(book._shelf)) <= 3
    assert seen == 720


def test_a_full_book_drops_the_oldest_cleared_first_and_counts() -> None:
    book = IncidentBook(max_incidents=50)
    for p in range(200):  # nobody acknowledges: cleared incidents pile up
        step(book, [zone(float(p), "enter", person=p)])
        step(book, [zone(p + 0.5, "exit", person=p)])
    step(book, [zone(300.0, "enter", person=999)])
    assert len(book) == 50 and book.dropped == 151
    ids = [r.id for r in book.incidents()]
    assert ids == [*range(152, 201), 201]  # the newest kept, the active one too
    assert book.get(201).state == ACTIVE


def test_restore_takes_open_incidents_back_once() -> None:
    ids = itertools.count(1)
    old = IncidentBook(next_id=ids.__next__)
    step(old, [zone(0.0, "enter"), camera(0.0, "camera_down"), zone(0.0, "approach", 2)])
    step(old, [camera(3.0, "camera_up")])
    old.shelve(1, "ann", "works", 600.0, 4.0)
    saved = old.incidents()
    new = IncidentBook(next_id=ids.__next__)  # the caller's high-water mark goes on
    assert new.restore(saved) == 3 and new.restore(saved) == 0
    assert new.incidents() == saved
    up = step(new, [zone(10.0, "dwell"), camera(10.0, "camera_down"), zone(10.0, "enter", 3)])
    assert up.incidents == (1, 2, 4) and len(up.notifications) == 1
    assert new.get(2).state == ACTIVE and new.get(2).occurrences == 2
    assert whats(step(new, [], 604.0))[0] == ("unshelved", ACTIVE, ACTIVE)
    # the approach of person 2 clears after its quiet time, as before the restart
    assert new.get(3).state == CLEARED


def test_shelving_holds_for_the_hazard_until_it_runs_out() -> None:
    """A camera flapping during maintenance: its new incidents are born shelved, quiet."""
    book = IncidentBook()
    step(book, [camera(0.0, "camera_down")])
    book.shelve(1, "ann", "maintenance", 3600.0, 1.0)
    for k in range(1, 5):  # down for 10 s every 5 minutes: each time past the re-arm
        step(book, [camera(300.0 * k - 290.0, "camera_up")])
        book.acknowledge(book.incidents()[-1].id, "ann", 300.0 * k - 289.0)
        up = step(book, [camera(300.0 * k, "camera_down")])
        (c,) = up.changes
        assert (c.what, c.notify, c.incident.shelved, c.incident.shelved_until) == (
            "raised",
            False,
            True,
            3601.0,
        )
        assert c.incident.shelved_reason == "maintenance" and c.incident.shelved_by == "ann"
    assert len(book) <= 2  # the closed ones are forgotten all the same
    up = step(book, [], 3601.0)
    assert [(c.what, c.incident.id) for c in up.changes] == [("unshelved", 5)]
    step(book, [camera(3700.0, "camera_up")])
    up = step(book, [camera(4000.0, "camera_down")])
    assert [c.incident.id for c in up.notifications] == [6]  # the shelving has run out
    # an operator's unshelving ends it for the hazard at once
    book.shelve(6, "ann", "again", 600.0, 4001.0)
    book.unshelve(6, "ann", 4002.0)
    step(book, [camera(4003.0, "camera_up")])
    assert len(step(book, [camera(4100.0, "camera_down")]).notifications) == 1
