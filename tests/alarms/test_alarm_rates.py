"""Alarm-rate figures: notifications per 10 minutes and hour against the flood line,
chattering (notifications and occurrences), standing incidents, bounded memory."""

from __future__ import annotations

from alarm_events import zone

from stereopose.alarms import AlarmRates, AlarmSettings, IncidentBook, Tuning
from stereopose.alarms.rates import FLOOD_PER_10MIN


def feed(book: IncidentBook, rates: AlarmRates, events) -> None:
    for e in events:
        rates.observe(book.update([e], e.t).changes)


def test_notifications_in_the_last_10_minutes_and_hour_against_the_flood_line() -> None:
    book, rates = IncidentBook(), AlarmRates()
    # a new person at the panel every 30 s for an hour: 120 incidents
    feed(book, rates, [zone(30.0 * k, "enter", person=k) for k in range(120)])
    f = rates.figures(3570.0, book.incidents())
    assert f.notifications_10min == 20 and f.notifications_1h == 120
    assert f.flood_line == FLOOD_PER_10MIN == 10 and f.flood
    assert (f.chattering, f.chattering_occurrences) == (0, 0)
    f = rates.figures(3570.0 + 601.0)
    assert (f.notifications_10min, f.flood) == (0, False) and f.notifications_1h == 100


def test_the_book_turns_chattering_notifications_into_occurrences() -> None:
    reach = []
    for k in range(6):  # in and out of the panel every 8 s
        reach += [zone(8.0 * k, "enter"), zone(8.0 * k + 2.0, "exit")]
    # without re-arm each return is a new incident: 6 notifications of one hazard in 42 s
    book, rates = IncidentBook(AlarmSettings(zones={"panel": Tuning(None, 0.0)})), AlarmRates()
    feed(book, rates, reach)
    f = rates.figures(45.0, book.incidents())
    assert (f.notifications_10min, f.chattering, f.chattering_occurrences) == (6, 1, 0)
    # with the default re-arm: one notification, one incident that chatters
    book, rates = IncidentBook(), AlarmRates()
    feed(book, rates, reach)
    f = rates.figures(45.0, book.incidents())
    assert (f.notifications_10min, f.chattering, f.chattering_occurrences) == (1, 0, 1)
    # a minute later nothing chatters any more
    f = rates.figures(45.0 + 61.0, book.incidents())
    assert (f.chattering, f.chattering_occurrences) == (0, 0)


def test_standing_incidents() -> None:
    book, rates = IncidentBook(), AlarmRates(standing_s=3600.0)
    feed(book, rates, [zone(0.0, "enter", person=1), zone(1000.0, "enter", person=2)])
    assert rates.figures(3600.0, book.incidents()).standing == 0
    assert rates.figures(3600.5, book.incidents()).standing == 1
    feed(book, rates, [zone(3700.0, "exit", person=1)])
    assert rates.figures(4600.5, book.incidents()).standing == 1  # person 2 only


def test_memory_is_bounded_and_drops_are_counted() -> None:
    book, rates = IncidentBook(), AlarmRates(max_events=50)
    feed(book, rates, [zone(float(k), "enter", person=k) for k in range(80)])
    assert rates.figures(80.0).notifications_1h == 50
    assert rates.dropped == 30 and rates.dropped_occurrences == 30
    feed(book, rates, [zone(5000.0, "enter", person=999)])
    assert len(rates._notified) == 1 and len(rates._occurred) == 1
    assert rates.figures(5000.0).to_dict()["dropped"] == 30
