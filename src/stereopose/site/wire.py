"""The event log's outbox protocol over MQTT as the site sends it and a control room reads it
(docs/mqtt.md, "The event log outbox"): the topics under `<prefix>/<site>/`, which side sends
each, and the control messages' bodies. The site's outbox (site.outbox) and the control room's
ingest (controlroom.ingest) both build their topics and bodies here, so the two sides cannot
drift apart.

    topics = site_topics("stereopose", "north/yard")  # {"events": "stereopose/north%2Fyard/...
    split_topic("stereopose", msg.topic)  # ("north/yard", "log/events"), or None
    replay_body(120)  # '{"after_id": 120}'
"""

from __future__ import annotations

import json

from stereopose.io.sinks.mqtt_settings import topic_name, topic_part

__all__ = [
    "AVAILABLE",
    "COMMAND_ACK",
    "COMMAND_DONE",
    "CONFIRMED",
    "EVENTS",
    "HEARTBEAT",
    "INCIDENTS",
    "PEOPLE",
    "PLAN",
    "REPLAY",
    "ack_body",
    "confirmed_body",
    "receiver_subscriptions",
    "replay_body",
    "site_topic",
    "site_topics",
    "split_topic",
]

# what follows `<prefix>/<site>/` (the site's name as one topic level: io.sinks.mqtt_settings)
EVENTS = "log/events"  # site -> receiver, QoS 1: each event of the log with its `prev`
INCIDENTS = "log/incidents"  # site -> receiver, QoS 1: each incident change with its `prev`
CONFIRMED = "log/confirmed"  # receiver -> site, retained: the marks stored
REPLAY = "log/replay"  # receiver -> site: send again after a mark
HEARTBEAT = "log/heartbeat"  # site -> receiver, QoS 0: the last ids, the clock, the summary
COMMAND_ACK = "commands/ack"  # receiver -> site: acknowledge an incident
COMMAND_DONE = "commands/done"  # site -> receiver: a command's answer
PLAN = "plan"  # site -> receiver, retained: the zones and the console's address
AVAILABLE = "available"  # site (the MQTT sink's will) -> receiver, retained: online/offline
PEOPLE = "people"  # site (the MQTT sink) -> anyone: the people now

_KEYS = {
    "events": EVENTS,
    "incidents": INCIDENTS,
    "confirmed": CONFIRMED,
    "replay": REPLAY,
    "heartbeat": HEARTBEAT,
    "ack": COMMAND_ACK,
    "done": COMMAND_DONE,
    "plan": PLAN,
}


def site_topic(prefix: str, site: str, what: str) -> str:
    """The topic of `what` (EVENTS, REPLAY, ...) for `site`."""
    return f"{prefix}/{topic_part(site)}/{what}"


def site_topics(prefix: str, site: str) -> dict[str, str]:
    """Every topic of the outbox for `site`, by short name: events, incidents, confirmed,
    replay, heartbeat, ack, done, plan."""
    return {key: site_topic(prefix, site, what) for key, what in _KEYS.items()}


def split_topic(prefix: str, topic: str) -> tuple[str, str] | None:
    """(site, what) of a topic under `<prefix>/<site>/`; None when it is not one (what may be
    anything: the receiver judges whether it is a topic of the protocol)."""
    if not topic.startswith(prefix + "/"):
        return None
    rest = topic[len(prefix) + 1 :].split("/")
    if len(rest) < 2:
        return None
    return topic_name(rest[0]), "/".join(rest[1:])


def receiver_subscriptions(prefix: str, share: str = "") -> list[tuple[str, int]]:
    """A control room's subscriptions over every site (`share`: a shared-subscription prefix,
    `$share/<group>/`, so that workers split the sites' messages; the plan is unshared: every
    worker's pages need every site's)."""
    shared = [(EVENTS, 1), (AVAILABLE, 1), (HEARTBEAT, 0), (INCIDENTS, 1), (COMMAND_DONE, 1)]
    return [(f"{share}{prefix}/+/{what}", qos) for what, qos in shared] + [
        (f"{prefix}/+/{PLAN}", 1)
    ]


def confirmed_body(events: int, incidents: int) -> str:
    """The marks a receiver stored, on CONFIRMED (retained: the site's cursors restart after)."""
    return json.dumps({"events": int(events), "incidents": int(incidents)})


def replay_body(mark: int, incidents: bool = False) -> str:
    """Ask the site to send again after `mark`: its events', or its incident changes'."""
    return json.dumps({"incidents_after": int(mark)} if incidents else {"after_id": int(mark)})


def ack_body(command: str, incident: int, by: str, where: str) -> str:
    """An acknowledgement of `incident` by `by` at the control room `where`, on COMMAND_ACK
    (answered on COMMAND_DONE by `command`)."""
    return json.dumps({"command": str(command), "incident": incident, "by": by, "from": where})
