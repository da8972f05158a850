"""The outbox protocol's topics and bodies, shared by the site's outbox and the control room."""

from __future__ import annotations

import json

import pytest

from stereopose.site.wire import (
    CONFIRMED,
    EVENTS,
    PLAN,
    ack_body,
    confirmed_body,
    id_of,
    parse_ack,
    receiver_subscriptions,
    replay_body,
    site_topic,
    site_topics,
    split_topic,
)


@pytest.mark.parametrize("site", ["north", "north/yard", "a+b#c", "100%", "", "站 1"])
def test_a_sites_topics_name_it_back_whatever_its_name(site: str) -> None:
    topics = site_topics("stereopose", site)
    assert set(topics) == {
        "events",
        "incidents",
        "confirmed",
        "replay",
        "heartbeat",
        "ack",
        "done",
        "plan",
    }
    for what_topic in topics.values():
        got = split_topic("stereopose", what_topic)
        assert got is not None and got[0] == site
        assert what_topic.count("/") == 2 + got[1].count("/")  # the site is one level
    assert split_topic("stereopose", topics["events"]) == (site, EVENTS)


@pytest.mark.parametrize(
    "topic",
    ["other/north/log/events", "stereopose", "stereopose/north", "stereoposeX/north/log/events"],
)
def test_a_topic_outside_the_prefix_or_without_a_part_is_none(topic: str) -> None:
    assert split_topic("stereopose", topic) is None


def test_the_receivers_subscriptions_share_all_but_the_plan() -> None:
    subs = dict(receiver_subscriptions("p", "$share/room/"))
    assert subs["$share/room/p/+/" + EVENTS] == 1
    assert subs["p/+/" + PLAN] == 1
    assert all(t.startswith("$share/room/") for t in subs if not t.endswith(PLAN))


def test_the_control_bodies() -> None:
    assert json.loads(confirmed_body(5, 2)) == {"events": 5, "incidents": 2}
    assert json.loads(replay_body(7)) == {"after_id": 7}
    assert json.loads(replay_body(7, incidents=True)) == {"incidents_after": 7}
    ack = {"command": "c1", "incident": 4, "by": "otto", "from": "room"}
    assert json.loads(ack_body("c1", 4, "otto", "room")) == ack
    assert site_topic("p", "a/b", CONFIRMED) == "p/a%2Fb/log/confirmed"


def test_an_acknowledgement_command_is_read_back_or_refused() -> None:
    assert parse_ack(ack_body("c1", 4, "otto", "room").encode()) == ("c1", 4, "otto via room")
    for bad in (
        b"not json",
        b"[1]",
        b'{"command": "c", "incident": -1, "by": "a", "from": "b"}',
        b'{"command": "c", "incident": true, "by": "a", "from": "b"}',
        b'{"command": "c", "incident": 1, "by": "", "from": "b"}',
        b'{"command": "c", "incident": 1, "by": "a\\n", "from": "b"}',
        b"[" * 20_000,
    ):
        assert parse_ack(bad) is None, bad[:40]
    assert id_of(b'{"after_id": 7}', "after_id") == 7
    assert id_of(b'{"after_id": 1e400}', "after_id") is None
    assert id_of(b'{"after_id": 9223372036854775808}', "after_id") is None
