"""What an outbox message, a heartbeat and a plan may hold before the control room takes
them: every number within what a store holds (integers of 64 bits, finite floats), strings,
keys and lists of bounded length, nesting at most MAX_DEPTH deep."""

from __future__ import annotations

import json
import math

MAX_ID = 2**63 - 1
MAX_DEPTH = 8  # an outbox message nests no deeper (an event, an incident's record)
MAX_TEXT = 4096  # characters of one string in an outbox message at most
MAX_ITEMS = 256  # keys of one object, items of one list, at most
SUMMARY_COUNTS = ("cameras", "cameras_up", "people")  # a heartbeat's summary: these, status
MAX_STATUS = 32  # characters of a heartbeat's status at most
MAX_COUNT = 1_000_000  # a heartbeat's cameras, cameras_up, people at most


def numbered(payload: bytes, key: str) -> dict | None:
    """An outbox message with an int `key` and prev, every number in it within what a store
    holds, nested at most MAX_DEPTH deep; or None."""
    try:
        e = json.loads(payload)
    except (ValueError, UnicodeDecodeError, RecursionError):
        return None
    if not isinstance(e, dict) or not sane(e):
        return None
    for k in (key, "prev"):
        if not is_id(e.get(k)):
            return None
    p = e.get("priority")
    if p is not None and (isinstance(p, bool) or p not in (1, 2, 3, 4)):
        return None
    return e


def is_id(v: object) -> bool:
    """Whether `v` is an event id or sequence number: an int from 0 to MAX_ID."""
    return isinstance(v, int) and not isinstance(v, bool) and 0 <= v <= MAX_ID


def sane(value: object, depth: int = 0) -> bool:
    """Whether every number in `value` fits a store (int64, finite), every string and key is
    at most MAX_TEXT characters, every object and list at most MAX_ITEMS long, and it nests
    at most MAX_DEPTH deep (below `depth`)."""
    if depth > MAX_DEPTH:
        return False
    if isinstance(value, bool) or value is None:
        return True
    if isinstance(value, str):
        return len(value) <= MAX_TEXT
    if isinstance(value, int):
        return -(2**63) <= value <= MAX_ID
    if isinstance(value, float):
        return math.isfinite(value)
    if isinstance(value, dict):
        return len(value) <= MAX_ITEMS and all(
            len(k) <= MAX_TEXT and sane(v, depth + 1) for k, v in value.items()
        )
    if isinstance(value, list):
        return len(value) <= MAX_ITEMS and all(sane(v, depth + 1) for v in value)
    return False


def summary(beat: dict) -> dict:
    """A heartbeat's summary of its site, each field checked: a short status, counts in
    range; anything else left out."""
    out: dict[str, object] = {}
    status = beat.get("status")
    if isinstance(status, str) and 0 < len(status) <= MAX_STATUS and status.isprintable():
        out["status"] = status
    for k in SUMMARY_COUNTS:
        v = beat.get(k)
        if isinstance(v, int) and not isinstance(v, bool) and 0 <= v <= MAX_COUNT:
            out[k] = v
    return out


def incident_change(msg: dict) -> bool:
    """Whether an incident change carries an incident record with an id."""
    rec = msg.get("incident")
    return isinstance(rec, dict) and is_id(rec.get("id"))


def heartbeat(payload: bytes) -> tuple[dict, int, float] | None:
    """(the heartbeat, its last id, when it was sent) or None when it is not one."""
    try:
        beat = json.loads(payload)
        last, sent = beat["last_id"], float(beat["time"])
    except (ValueError, TypeError, KeyError, UnicodeDecodeError, OverflowError, RecursionError):
        return None
    if not is_id(last) or not math.isfinite(sent):
        return None
    return beat, last, sent
