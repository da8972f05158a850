"""The control room's store, the same contract on SQLite and on a real PostgreSQL: each
(site, id) once whatever is resent, the marks only rising, an incident's newer record
replacing an older one and never the reverse, acknowledgements asked and answered, the
control room's own incidents through their states; a PostgreSQL server restarted under a
running store is reconnected; a store that cannot be reached is a clear StoreError."""

from __future__ import annotations

import uuid

import pytest

from stereopose.controlroom.store import ControlStore, StoreError, shown_database


@pytest.fixture(params=["sqlite", "postgresql"])
def store(request, tmp_path):
    if request.param == "sqlite":
        s = ControlStore(tmp_path / "control.sqlite")
    else:
        pg = request.getfixturevalue("postgres")
        s = ControlStore(pg.database(f"t{uuid.uuid4().hex[:12]}"))
    yield s
    s.close()


def _events(ids, site="north"):
    return [
        {
            "id": i,
            "prev": i - 1,
            "site": site,
            "type": "enter",
            "zone": "bus",
            "person": 2,
            "wall_t": 1.8e9 + i,
            "incident": 1,
            "priority": 1,
        }
        for i in ids
    ]


def _change(seq, incident=1, state="active", acked_by=None):
    return {
        "seq": seq,
        "incident": {
            "id": incident,
            "state": state,
            "priority": 1,
            "zone": "bus",
            "person": 2,
            "last_wall_t": 1.8e9 + seq,
            "acked_by": acked_by,
            "occurrences": seq,
        },
    }


def test_each_event_once_and_the_marks_only_rise(store):
    assert store.put_events("north", _events([1, 2, 3]), 3, 10.0) == 3
    assert store.put_events("north", _events([2, 3, 4]), 4, 11.0) == 1  # resent: once
    assert store.put_events("north", _events([1]), 1, 12.0) == 0  # an old mark never lowers
    assert store.marks() == {"north": 4}
    assert store.duplicates == 3 and store.stored == 4
    assert [e["id"] for e in store.events("north", 0, 100)] == [1, 2, 3, 4]
    assert [e["id"] for e in store.events("north", 2, 1)] == [3]
    store.put_events("south", _events([1], "south"), 1, 13.0)
    assert [(e["site"], e["id"]) for e in store.events(sites=["south"])] == [("south", 1)]
    assert store.events(sites=[]) == []
    rows = {r.site: r for r in store.sites()}
    assert rows["north"].events == 4 and rows["north"].mark == 4
    store.set_site("north", state="offline", last_seen=20.0)
    store.set_summaries({"north": {"cameras": 4, "cameras_up": 3, "people": 2}})
    north = {r.site: r for r in store.sites(["north"])}["north"]
    assert north.state == "offline" and north.health["cameras_up"] == 3
    assert north.last_seen == pytest.approx(20.0)


def test_a_newer_incident_record_replaces_an_older_one_never_the_reverse(store):
    store.put_incidents("north", [_change(1), _change(2, incident=2)], 2, 10.0)
    store.put_incidents("north", [_change(5, state="acknowledged", acked_by="sam")], 5, 11.0)
    store.put_incidents("north", [_change(3, state="active")], 3, 12.0)  # a late resend
    rec = store.incident("north", 1)
    assert rec["state"] == "acknowledged" and rec["acked_by"] == "sam" and rec["site"] == "north"
    assert store.incident_marks() == {"north": 5}
    assert store.open_counts() == {"north": {"1": 2}}
    listed = store.incidents(site="north", state="open")
    assert sorted(i["id"] for i in listed) == [1, 2]
    assert store.incidents(state="closed") == []
    assert store.incident("north", 99) is None


def test_acknowledgements_asked_and_answered_and_the_rooms_incidents(store):
    store.put_incidents("north", [_change(1)], 1, 10.0)
    command = store.add_command("north", 1, "olga", 11.0)
    assert store.pending_commands() == [(command, "north", 1, "olga")]
    pending = store.incidents(site="north")[0]["ack_pending"]
    assert pending == [{"by": "olga", "asked_at": 11.0}]
    assert store.finish_command(command, "acknowledged", 12.0) is True
    assert store.finish_command(command, "already", 13.0) is False  # answered once
    assert store.pending_commands() == []
    first = store.raise_room_incident("north", "site_offline", 2, "the site is offline", 14.0)
    assert first is not None
    assert store.raise_room_incident("north", "site_offline", 2, "again", 15.0) is None
    acked = store.ack_room_incident(first, "olga", 16.0)
    assert acked["state"] == "acknowledged" and acked["source"] == "control_room"
    assert store.clear_room_incidents("north", "site_offline", 17.0) == 1
    closed = [i for i in store.incidents(site="north") if i["source"] == "control_room"]
    assert closed[0]["state"] == "closed" and closed[0]["cleared_wall_at"] == 17.0
    assert store.ack_room_incident(12345, "olga", 18.0) is None


def test_a_postgresql_server_restarted_under_a_running_store_is_reconnected(postgres):
    store = ControlStore(postgres.database(f"t{uuid.uuid4().hex[:12]}"))
    try:
        store.put_events("north", _events([1, 2]), 2, 10.0)
        postgres.stop()
        with pytest.raises(StoreError, match="cannot store 1 event"):
            store.put_events("north", _events([3]), 3, 11.0)
        with pytest.raises(StoreError, match="cannot read the events"):
            store.events("north")
        postgres.start()
        assert store.put_events("north", _events([3]), 3, 12.0) == 1
        assert [e["id"] for e in store.events("north")] == [1, 2, 3]
    finally:
        store.close()


def test_a_store_that_cannot_be_reached_is_a_clear_error_without_its_password(postgres):
    url = f"postgresql://stereopose:sekrit-word@127.0.0.1:{postgres.port + 1}/none"
    with pytest.raises(StoreError) as e:
        ControlStore(url)
    assert "sekrit-word" not in str(e.value) and "cannot open the control room's store" in str(
        e.value
    )
    assert shown_database(url) == f"postgresql://stereopose:***@127.0.0.1:{postgres.port + 1}/none"


def test_many_sites_in_one_transaction(store):
    new, written = store.put_batch(
        {"north": (_events([1, 2]), 2), "south": (_events([1], "south"), 1)},
        {"north": ([_change(1), _change(2, state="cleared")], 2)},
        10.0,
    )
    assert (new, written) == (3, 2)  # incident 1 written twice, its newer record last
    assert store.incident("north", 1)["state"] == "cleared"
    new, _ = store.put_batch({"north": (_events([2, 3]), 3)}, {}, 11.0)
    assert new == 1 and store.marks() == {"north": 3, "south": 1}
    assert store.incident_marks()["north"] == 2 and store.duplicates == 1


def test_old_rows_are_pruned_and_the_marks_stay(store):
    store.put_events("north", _events([1, 2]), 2, 10.0)
    store.put_events("north", _events([3]), 3, 100.0)
    store.put_incidents("north", [_change(1, state="closed")], 1, 10.0)
    store.put_incidents("north", [_change(2, incident=2)], 2, 10.0)  # open: kept
    done = store.add_command("north", 2, "olga", 10.0)
    store.finish_command(done, "acknowledged", 11.0)
    waiting = store.add_command("north", 2, "paul", 12.0)  # not answered: kept
    room = store.raise_room_incident("north", "site_offline", 2, "offline", 10.0)
    store.ack_room_incident(room, "olga", 11.0)
    store.clear_room_incidents("north", "site_offline", 12.0)  # closed at 12
    assert store.prune(50.0) == 5
    assert [e["id"] for e in store.events("north")] == [3]
    assert [i["id"] for i in store.incidents(site="north")] == [2]
    assert [c for c, *_ in store.pending_commands()] == [waiting]
    assert store.marks() == {"north": 3} and store.incident_marks() == {"north": 2}
    assert store.room_incident(room) is None
