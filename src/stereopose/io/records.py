"""People3D and Event to and from their JSON records: the one place the file contracts are
written and read (poses and events JSON lines, SQLite rows, the webhook body, the report).

3D poses, one record per frame (docs/formats.md), frames with nobody included:
{"frame": 42, "t": 1.68, "people": [{"id": 3, "joints": [[x, y, z] or null, ...17],
 "conf": [...17], "position": [x, y], "velocity": [vx, vy], "speed": 0.8, "heading_deg": 91.5,
 "predicted": false, "views": [...17], "reprojection_px": 2.1, "posture": "standing",
 "flags": ["arms_raised"]}]}
Metres, world frame; joints to 0.1 mm, conf to 1e-3, velocity and speed (m/s) to 1 mm/s,
heading (degrees counter-clockwise from world +x) to 0.1 degree, the person's mean
reprojection error (pixels) to 0.01 px; `posture` and `flags` (behaviour.posture) only when
the site has behaviour rules. Only `frame`, `people[].id` and `people[].joints` are
required when reading.

Events: {"t": 2.12, "frame": 53, "person": 3, "zone": "work_area_1", "kind": "work_area",
"type": "enter", "onset_t": 2.04, "joint": "right_wrist", "position": [x, y]}, with
`distance_m`, `duration_s`, `allowed`, `lost` and `restart` when they apply. Camera events
add `camera` and, for the calibration's health, `reprojection_px` and `baseline_px`.
Behaviour events (kind "behaviour") add `rule` and, where they apply, `posture`, `nearest_m`,
`facing_deg`, `failed`, `height_m` and `speed_m_s`.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from typing import Any, SupportsFloat

import numpy as np

from stereopose.skeleton import NUM_JOINTS, floor_position, heading_deg
from stereopose.types import Event, JsonDoc, People3D

__all__ = [
    "EVENT_COLUMNS",
    "event_from_record",
    "event_record",
    "event_row",
    "frame_record",
    "parse_frame_record",
    "people3d_from_record",
]

# the SQLite event log's columns, in order (see io.sinks.events)
EVENT_COLUMNS = (
    "run",
    "t",
    "frame",
    "person",
    "zone",
    "kind",
    "type",
    "onset_t",
    "joint",
    "distance_m",
    "duration_s",
    "x",
    "y",
    "allowed",
    "lost",
    "restart",
    "camera",
    "reprojection_px",
    "baseline_px",
    "rule",
    "posture",
    "nearest_m",
    "facing_deg",
    "failed",
    "height_m",
    "speed_m_s",
    "incident",
    "priority",
    "ticket",
    "step",
    "result",
    "source",
)
# the behaviour events' optional fields: (name, decimals; None for text)

_BEHAVIOUR_FIELDS = (
    ("rule", None),
    ("posture", None),
    ("nearest_m", 4),
    ("facing_deg", 1),
    ("failed", None),
    ("height_m", 4),
    ("speed_m_s", 3),
)


def _round(x: float, nd: int) -> float | None:
    return None if not math.isfinite(x) else round(float(x), nd)


def _pair(v: list[float], nd: int) -> list[float] | None:
    a, b = v
    return [round(a, nd), round(b, nd)] if math.isfinite(a) and math.isfinite(b) else None


def _person_record(row: tuple) -> dict:
    """One person's record from a row of plain Python values (NaN: unknown): id, joints,
    conf, floor position, heading, velocity, predicted, views, mean reprojection error."""
    pid, joints, conf, position, heading, velocity, predicted, views, reprojection_px = row
    vx, vy = velocity
    return {
        "id": pid,
        "joints": [
            [round(x, 4), round(y, 4), round(z, 4)] if x == x and y == y and z == z else None
            for x, y, z in joints
        ],
        "conf": [round(c, 3) for c in conf],
        "position": _pair(position, 4),
        "velocity": _pair(velocity, 3),
        "speed": _round(math.hypot(vx, vy), 3),
        "heading_deg": _round(heading, 1),
        "predicted": predicted,
        "views": views,
        "reprojection_px": _round(reprojection_px, 2),
    }


def frame_record(people: People3D, fps: float, postures: Mapping[int, Any] | None = None) -> dict:
    """The JSON object of one frame of 3D people; t: the frame's time (People3D.time).
    postures: person id -> posture (behaviour.posture.Posture) when behaviour rules run: each
    person with one gets `"posture"` and `"flags"`."""
    P = len(people)
    out = []
    if P:
        err = people.reprojection_px
        seen = ~np.isnan(err)
        n = seen.sum(-1)
        total = np.where(seen, err, 0.0).sum(-1)
        mean_err = np.divide(total, n, out=np.full(P, np.nan), where=n > 0)  # NaN: no view
        J = np.where(np.isfinite(people.joints).all(-1, keepdims=True), people.joints, np.nan)
        columns = (
            people.ids.tolist(),
            J.tolist(),
            people.conf.tolist(),
            floor_position(people.joints).tolist(),
            heading_deg(people.joints).tolist(),
            np.asarray(people.velocity).tolist(),
            np.asarray(people.predicted).tolist(),
            people.views.tolist(),
            mean_err.tolist(),
        )
        out = [_person_record(row) for row in zip(*columns, strict=True)]
        if postures:
            for rec in out:
                pos = postures.get(rec["id"])
                if pos is not None:
                    rec["posture"], rec["flags"] = pos.posture, list(pos.flags)
    return {"frame": people.frame, "t": round(people.time(fps), 6), "people": out}


def _joints_array(joints: Sequence[Sequence[float] | None]) -> np.ndarray:
    """(17, 3) from a record's joints, NaN for null."""
    return np.array([j if j is not None else [np.nan] * 3 for j in joints], dtype=float).reshape(
        NUM_JOINTS, 3
    )


def parse_frame_record(rec: JsonDoc) -> tuple[int, float | None, list[dict]]:
    """(frame, t, people) of one frame record; each person keeps its JSON fields and gains
    `joints_array` (17, 3) with NaN for null. Raises KeyError, TypeError or ValueError on a
    malformed record (the reader names the file and line)."""
    frame = int(rec["frame"])
    people = rec["people"]
    for p in people:
        p["joints_array"] = _joints_array(p["joints"])
        int(p["id"])
    t = rec.get("t")
    return frame, None if t is None else float(t), people


def people3d_from_record(frame: int, people: Sequence[JsonDoc], num_cameras: int = 0) -> People3D:
    """People3D from the people of a parsed frame record (see `parse_frame_record`).

    Restored: joints, conf (default: 1 where a joint is given), ids, views (default 0),
    predicted, velocity. Not stored, so not restored: the per-joint reprojection errors (NaN)
    and which detection each camera gave (-1 for each of `num_cameras`)."""
    P = len(people)
    joints = np.array(
        [p["joints_array"] if "joints_array" in p else _joints_array(p["joints"]) for p in people]
    ).reshape(P, NUM_JOINTS, 3)
    conf = np.array(
        [p.get("conf") or np.isfinite(joints[i]).all(-1) for i, p in enumerate(people)], float
    ).reshape(P, NUM_JOINTS)
    views = np.array([p.get("views") or [0] * NUM_JOINTS for p in people], dtype=np.int64)
    return People3D(
        frame=frame,
        joints=joints,
        conf=conf,
        ids=np.array([p["id"] for p in people], dtype=np.int64),
        reprojection_px=np.full((P, NUM_JOINTS), np.nan),
        views=views.reshape(P, NUM_JOINTS),
        detections=np.full((P, num_cameras), -1, dtype=np.int64),
        predicted=np.array([bool(p.get("predicted", False)) for p in people], dtype=bool),
        velocity=np.array(
            [p.get("velocity") or [np.nan, np.nan] for p in people], dtype=float
        ).reshape(P, 2),
    )


def event_record(e: Event) -> dict:
    """The JSON object of the events contract (optional fields only when they apply); times
    to 1 us, distances and durations to 0.1 mm / 0.1 ms, the position to 0.1 mm."""
    d: dict = {
        "t": round(e.t, 6),
        "frame": e.frame,
        "person": e.person,
        "zone": e.zone,
        "kind": e.kind,
        "type": e.type,
        "onset_t": round(e.onset_t, 6),
    }
    if e.joint is not None:
        d["joint"] = e.joint
    if e.distance_m is not None:
        d["distance_m"] = round(e.distance_m, 4)
    if e.duration_s is not None:
        d["duration_s"] = round(e.duration_s, 4)
    d["position"] = [round(e.position[0], 4), round(e.position[1], 4)] if e.position else None
    if e.allowed:
        d["allowed"] = True
    if e.lost:
        d["lost"] = True
    if e.restart:
        d["restart"] = True
    if e.camera is not None:
        d["camera"] = e.camera
    for key, value in (("reprojection_px", e.reprojection_px), ("baseline_px", e.baseline_px)):
        if value is not None:
            d[key] = _round(value, 3)
    behaviour = (e.rule, e.posture, e.nearest_m, e.facing_deg, e.failed, e.height_m, e.speed_m_s)
    for (key, nd), value in zip(_BEHAVIOUR_FIELDS, behaviour, strict=True):
        if value is not None:
            d[key] = value if nd is None or isinstance(value, str) else _round(value, nd)
    d["incident"] = e.incident  # always there: null for info events (or no incident book)
    d["priority"] = e.priority
    if e.ticket is not None:
        d["ticket"] = e.ticket
    if e.step is not None:
        d["step"] = e.step
    if e.result is not None:
        d["result"] = e.result
    if e.source is not None:
        d["source"] = e.source
    return d


def event_from_record(d: JsonDoc) -> Event:
    """An Event from its JSON object (or an SQLite row as a dict: `x`, `y` for the position).
    Raises KeyError, TypeError, ValueError or IndexError when a required field is missing or
    malformed."""
    pos = d.get("position")
    if pos is None and d.get("x") is not None and d.get("y") is not None:
        pos = (d["x"], d["y"])
    return Event(
        t=float(d["t"]),
        frame=int(d["frame"]),
        person=int(d["person"]),
        zone=str(d["zone"]),
        kind=str(d.get("kind", "")),
        type=str(d["type"]),
        onset_t=float(d["t"] if d.get("onset_t") is None else d["onset_t"]),
        joint=d.get("joint"),
        distance_m=None if d.get("distance_m") is None else float(d["distance_m"]),
        duration_s=None if d.get("duration_s") is None else float(d["duration_s"]),
        position=(float(pos[0]), float(pos[1])) if pos else None,
        allowed=bool(d.get("allowed", False)),
        lost=bool(d.get("lost", False)),
        restart=bool(d.get("restart", False)),
        camera=None if d.get("camera") is None else str(d["camera"]),
        reprojection_px=_optional_float(d.get("reprojection_px")),
        baseline_px=_optional_float(d.get("baseline_px")),
        rule=_optional_str(d.get("rule")),
        posture=_optional_str(d.get("posture")),
        nearest_m=_optional_float(d.get("nearest_m")),
        facing_deg=_optional_float(d.get("facing_deg")),
        failed=_optional_str(d.get("failed")),
        height_m=_optional_float(d.get("height_m")),
        speed_m_s=_optional_float(d.get("speed_m_s")),
        incident=None if d.get("incident") is None else int(d["incident"]),
        priority=None if d.get("priority") is None else int(d["priority"]),
        ticket=None if d.get("ticket") is None else str(d["ticket"]),
        step=None if d.get("step") is None else str(d["step"]),
        result=_result(d.get("result")),
        source=None if d.get("source") is None else str(d["source"]),
    )


def _result(value: object) -> dict | None:
    """ticket_completed's result: a dict, or its JSON text (an SQLite row's)."""
    if value is None or isinstance(value, dict):
        return value
    doc = json.loads(str(value))
    if not isinstance(doc, dict):
        raise ValueError(f"a ticket's result is an object, got {type(doc).__name__}")
    return doc


def _optional_float(value: SupportsFloat | str | None) -> float | None:
    return None if value is None else float(value)


def _optional_str(value: object) -> str | None:
    return None if value is None else str(value)


def event_row(e: Event, run: int) -> tuple:
    """The SQLite row of an event (EVENT_COLUMNS order), full precision."""
    x, y = e.position if e.position else (None, None)
    return (
        run,
        e.t,
        e.frame,
        e.person,
        e.zone,
        e.kind,
        e.type,
        e.onset_t,
        e.joint,
        e.distance_m,
        e.duration_s,
        x,
        y,
        int(e.allowed),
        int(e.lost),
        int(e.restart),
        e.camera,
        e.reprojection_px,
        e.baseline_px,
        e.rule,
        e.posture,
        e.nearest_m,
        e.facing_deg,
        e.failed,
        e.height_m,
        e.speed_m_s,
        e.incident,
        e.priority,
        e.ticket,
        e.step,
        None if e.result is None else json.dumps(e.result, separators=(",", ":")),
        e.source,
    )


def people_record(people: People3D, t: float, postures: Mapping[int, Any] | None = None) -> dict:
    """The people topic's JSON: the poses record's frame, t and, per person, id, position
    and heading_deg (the same fields and rounding as the 3D poses JSON lines), and posture and
    flags where the behaviour rules give them."""
    rec = frame_record(people, fps=1.0, postures=postures)  # its t is replaced by the frame's
    keep = ("id", "position", "heading_deg", "posture", "flags")
    return {
        "frame": rec["frame"],
        "t": round(t, 6),
        "people": [{k: p[k] for k in keep if k in p} for p in rec["people"]],
    }
