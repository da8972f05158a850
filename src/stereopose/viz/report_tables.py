"""The report's tables: the run summary, the cameras and the people, as HTML.

`check_summary` checks what they read of a summary.json first, so a damaged one is an error
naming the key, not a crash halfway through the page.
"""

from __future__ import annotations

import html
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from stereopose.types import Event

# summary.json keys the tables read as numbers (null allowed)
_NUMBERS = ("fps_input", "fps", "load_s_3d", "people_per_frame", "reprojection_median_px")
_CAMERA_NUMBERS = ("detections_per_frame", "reprojection_median_px", "reprojection_mean_px")
_PERSON_NUMBERS = ("duration_s", "path_m")
_REGION_NUMBERS = ("regions", "input_share", "whole_frames", "idle_steps", "full_scans", "steps")


def _is_number(v: object) -> bool:
    """A JSON number a table can format (null counts: it is shown as "-")."""
    if v is None:
        return True
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        return False
    try:
        float(v)
    except OverflowError:
        return False
    return True


def _numbers(d: dict, keys: tuple[str, ...], where: str) -> None:
    for k in keys:
        if not _is_number(d.get(k)):
            raise ValueError(f"{where}{k}: expected a number or null, got {_short(d.get(k))}")


def _short(v: object) -> str:
    """A value for a message: a scalar as written (if short), else its type."""
    if v is not None and not isinstance(v, (str, int, float)):
        return "an array" if isinstance(v, list) else "an object"
    text = "null" if v is None else repr(v) if not isinstance(v, int) or v.bit_length() < 64 else ""
    return text if text and len(text) <= 40 else f"a long {type(v).__name__}"


def _mapping(s: dict, key: str) -> dict:
    v = s.get(key, {})
    if not isinstance(v, dict):
        raise ValueError(f"{key}: expected an object, got {_short(v)}")
    return v


def check_summary(s: object) -> None:
    """Raise ValueError naming the key when a parsed summary.json cannot fill the tables."""
    if not isinstance(s, dict):
        raise ValueError(f"expected a JSON object, got {type(s).__name__}")
    _numbers(s, _NUMBERS, "")
    stages = _mapping(s, "fps_per_stage")
    _numbers(stages, tuple(stages), "fps_per_stage.")
    cameras = s.get("cameras", [])
    if not isinstance(cameras, list) or not all(isinstance(c, str) for c in cameras):
        raise ValueError(f"cameras: expected a list of names, got {_short(cameras)}")
    _mapping(s, "events")
    for key, numbers in (
        ("per_camera", _CAMERA_NUMBERS),
        ("sources", ()),
        ("regions", _REGION_NUMBERS),
    ):
        for name, c in _mapping(s, key).items():
            if not isinstance(c, dict):
                raise ValueError(f"{key}.{name}: expected an object, got {_short(c)}")
            _numbers(c, numbers, f"{key}.{name}.")
    people = s.get("people", [])
    if not isinstance(people, list):
        raise ValueError(f"people: expected a list, got {_short(people)}")
    for i, p in enumerate(people):
        if not isinstance(p, dict) or "id" not in p:
            raise ValueError(f"people[{i}]: expected an object with an id, got {_short(p)}")
        _numbers(p, _PERSON_NUMBERS, f"people[{i}].")


def _table(rows: list[list[str]], head: list[str]) -> str:
    th = "".join(f"<th>{html.escape(h)}</th>" for h in head)
    body = "".join(
        "<tr>" + "".join(f"<td>{html.escape(str(c))}</td>" for c in r) + "</tr>" for r in rows
    )
    return f"<table><thead><tr>{th}</tr></thead><tbody>{body}</tbody></table>"


def _fmt(v: float | None, unit: str = "", nd: int = 1) -> str:
    if v is None or (isinstance(v, float) and not np.isfinite(v)) or not _is_number(v):
        return "-"
    return f"{v:.{nd}f}{unit}"


def summary_html(s: dict) -> str:
    stages = s.get("fps_per_stage", {})
    source = "live" if s.get("live") else "recorded"
    people = f"{len(s.get('people', []))} tracked, {_fmt(s.get('people_per_frame'), '', 2)}"
    events = ", ".join(f"{v} {k}" for k, v in sorted(s.get("events", {}).items()))
    rows = [
        ["frames", str(s.get("frames"))],
        ["cameras", ", ".join(s.get("cameras", []))],
        ["input", f"{source}, {_fmt(s.get('fps_input'))} frames/s"],
        ["speed", f"{_fmt(s.get('fps'))} frames/s overall"],
        ["per stage", ", ".join(f"{k} {_fmt(v, ' f/s', 0)}" for k, v in stages.items())],
        *([["detector", _detector(s["detector"])]] if isinstance(s.get("detector"), dict) else []),
        ["3D stage loading", f"{_fmt(s.get('load_s_3d'), ' s', 2)} before the first frame"],
        ["people", f"{people} per frame"],
        ["events", events or "none"],
        ["median reprojection error", _fmt(s.get("reprojection_median_px"), " px")],
    ]
    if s.get("interrupted"):
        rows.append(["interrupted", "yes: the outputs end at the last complete frame"])
    return _table(rows, ["", ""])


def _detector(d: dict) -> str:
    """The detector's backend and precision, and why they were chosen."""
    what = f"{d.get('backend', '?')} {d.get('precision', '?')}"
    return f"{what} ({d['why']})" if d.get("why") else what


def cameras_html(s: dict) -> str:
    rows = []
    for name, c in s.get("per_camera", {}).items():
        src = s.get("sources", {}).get(name, {})
        rows.append(
            [
                name,
                c.get("frames"),
                _fmt(c.get("detections_per_frame"), "", 2),
                _fmt(c.get("reprojection_median_px"), " px"),
                _fmt(c.get("reprojection_mean_px"), " px"),
                src.get("dropped", 0),
                src.get("failures", 0),
                src.get("reconnects", 0),
            ]
        )
    head = [
        "camera",
        "frames",
        "detections/frame",
        "reprojection median",
        "reprojection mean",
        "dropped",
        "failures",
        "reconnects",
    ]
    regions = s.get("regions") or {}
    if regions:  # detection in regions: what each camera cost against whole frames
        head += [
            "regions/step",
            "model input of whole frames'",
            "whole / idle steps",
            "full scans",
            "newcomers: motion / scan",
        ]
        for row, name in zip(rows, s.get("per_camera", {}), strict=True):
            r = regions.get(name) or {}
            steps = r.get("steps") or 0
            row += [
                _fmt(r.get("regions", 0) / steps if steps else None, "", 1),
                _fmt(100 * r["input_share"] if _is_number(r.get("input_share")) else None, " %", 0),
                f"{r.get('whole_frames', '-')} / {r.get('idle_steps', '-')}",
                r.get("full_scans", "-"),
                f"{r.get('found_by_motion', '-')} / {r.get('found_by_scan', '-')}",
            ]
    return _table(rows, head)


def people_html(s: dict) -> str:
    rows = [
        [
            f"id {p['id']}",
            p.get("first_frame"),
            p.get("last_frame"),
            _fmt(p.get("duration_s")),
            p.get("frames_seen"),
            _fmt(p.get("path_m"), " m", 2),
        ]
        for p in s.get("people", [])
    ]
    return _table(
        rows, ["person", "first frame", "last frame", "time in view (s)", "frames seen", "path"]
    )


CSS = """
body { font-family: system-ui, sans-serif; margin: 1.5em auto; max-width: 1200px; color: #222; }
h1 { font-size: 1.5em; } h2 { font-size: 1.2em; margin-top: 1.6em; }
table { border-collapse: collapse; margin: 0.5em 0; }
td, th { border: 1px solid #ccc; padding: 3px 8px; text-align: left; font-size: 0.9em; }
pre { background: #f6f6f6; padding: 0.8em; overflow-x: auto; font-size: 0.85em; }
"""


def incidents_html(events: Sequence[Event]) -> str:
    """The run's alarms grouped by incident (the book `serve` keeps, as `run` keeps it too):
    per incident its priority, hazard, the worst and the latest of its event types, its first
    and last time and its occurrences; "" when the run raised none."""
    groups: dict[int, list] = {}
    for e in events:
        if e.incident is not None:
            groups.setdefault(int(e.incident), []).append(e)
    if not groups:
        return ""
    rows = []
    for i, es in sorted(groups.items()):
        es = sorted(es, key=lambda e: e.t)
        worst = min(es, key=lambda e: (e.priority if e.priority is not None else 9, e.t))
        hazard = " ".join(
            str(x)
            for x in (
                f"person {es[0].person}" if es[0].person >= 0 else "",
                es[0].zone or "",
                f"rule {es[0].rule}" if es[0].rule else "",
                es[0].camera or "",
            )
            if x
        )
        rows.append(
            [
                f"incident {i}",
                f"P{worst.priority}" if worst.priority else "-",
                hazard,
                worst.type,
                es[-1].type,
                _fmt(es[0].t, " s", 2),
                _fmt(es[-1].t, " s", 2),
                len(es),
            ]
        )
    return _table(
        rows, ["incident", "priority", "hazard", "worst", "latest", "first", "last", "occurrences"]
    )
