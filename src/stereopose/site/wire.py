"""The event log's outbox protocol over MQTT as the site sends it and a control room reads it
(docs/mqtt.md, "The event log outbox"): the topics under `<prefix>/<site>/`, which side sends
each, and the control messages' bodies. The site's outbox (site.outbox) and the control room's
ingest (controlroom.ingest) both build their topics and bodies here, so the two sides cannot
drift apart.

Topics under ``<prefix>/<site>/`` (docs/mqtt.md#the-event-log-outbox):

- ``log/events`` (the site publishes, QoS 1): each event of the event log as ``/api/events``
  answers it, plus ``site`` and ``prev``: the id of the event published before it in this
  stream (0 at the log's start). (site, id) names an event everywhere; ids only grow, and an
  id is never given again.
- ``log/incidents`` (the site publishes, QoS 1): ``{"site", "seq", "prev", "incident"}``: an
  incident's record (as ``/api/incidents`` answers it) after its last change, numbered by the
  log's change number ``seq`` (each write of an incident row takes the next one), ``prev`` the
  change published before it. An incident changed again is sent again with its new number;
  its older numbers are gone from the log, so the stream carries each incident's latest
  record, never a change lost between.
- ``log/confirmed`` (a receiver publishes, retained, QoS 1): ``{"events": N, "incidents": S}``,
  the highest event id and change number it has stored with nothing missing before them.
- ``log/replay`` (a receiver publishes, QoS 1): ``{"after_id": N}`` and/or
  ``{"incidents_after": S}``: send every stored event after id N (every incident changed
  after S) again.
- ``log/heartbeat`` (the site publishes every `heartbeat_s`, QoS 0): ``{"last_id": N,
  "last_incident_seq": S, "time": T, ...}``: the log's last numbers and the site's clock, so
  a receiver knows the site is there while nothing happens, sees the last events were lost
  when no later one shows it, and can tell how far the site's clock is from its own; with the
  site's summary (status, cameras, cameras_up, people, open_incidents) when the service
  gives one.
- ``commands/ack`` (a receiver publishes, QoS 1): ``{"command": C, "incident": I, "by": USER,
  "from": WHERE}``: acknowledge incident I as USER of WHERE (the site's book records
  ``"USER via WHERE"``); answered on ``commands/done`` (the site publishes, QoS 1) with
  ``{"command": C, "incident": I, "result": "acknowledged" | "already" | "unknown" |
  "unavailable"}``. Sent again until answered, a command acts at most once: an incident
  acknowledged stays so.
- ``plan`` (the site publishes at each connection, retained, QoS 1): ``{"zones": [{"name",
  "kind", "polygon"}], "console_url"}``: the site's zones (floor polygons, metres) and its own
  console's address (``[serve] public_url``), for a control room's page of the site.

A receiver stores a message whose ``prev`` is at most its own mark of that stream (nothing is
missing before it; a duplicate is dropped by its number) and raises its mark to the message's
number; one whose ``prev`` is beyond its mark means some were lost on the way (a bridge that
drops while cut, a broker restarted without them): it asks for a replay after its mark.

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


def ack_body(command: str | int, incident: int, by: str, where: str) -> str:
    """An acknowledgement of `incident` by `by` at the control room `where`, on COMMAND_ACK
    (answered on COMMAND_DONE by `command`)."""
    return json.dumps({"command": str(command), "incident": incident, "by": by, "from": where})


_MAX_ID = 2**63 - 1
COMMAND_KEYS = '{"command", "incident", "by", "from"}'
MAX_NAME = 64  # the longest user or place name a command may carry


def parse_ack(payload: bytes) -> tuple[str, int, str] | None:
    """(command id, incident id, "USER via WHERE") of an acknowledgement command, or None."""
    try:
        obj = json.loads(payload)
    except (ValueError, UnicodeDecodeError, RecursionError):
        return None
    if not isinstance(obj, dict):
        return None
    command, incident, by, where = (obj.get(k) for k in ("command", "incident", "by", "from"))
    if isinstance(incident, bool) or not isinstance(incident, int) or not 0 <= incident <= _MAX_ID:
        return None
    names = (command, by, where)
    if not all(isinstance(n, str) and 0 < len(n) <= MAX_NAME and n.isprintable() for n in names):
        return None
    return str(command), incident, f"{by} via {where}"


def id_of(payload: bytes, key: str) -> int | None:
    """The id under `key` of a JSON object payload, or None when malformed."""
    try:
        obj = json.loads(payload)
    except (ValueError, UnicodeDecodeError, RecursionError):
        return None
    value = obj.get(key) if isinstance(obj, dict) else None
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= _MAX_ID:
        return None
    return value
