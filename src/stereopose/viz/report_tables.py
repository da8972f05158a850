"""The report's tables: the run summary, the cameras and the people, as HTML."""

from __future__ import annotations

import html

import numpy as np


def _table(rows: list[list[str]], head: list[str]) -> str:
    th = "".join(f"<th>{html.escape(h)}</th>" for h in head)
    body = "".join(
        "<tr>" + "".join(f"<td>{html.escape(str(c))}</td>" for c in r) + "</tr>" for r in rows
    )
    return f"<table><thead><tr>{th}</tr></thead><tbody>{body}</tbody></table>"


def _fmt(v, unit: str = "", nd: int = 1) -> str:
    if v is None or (isinstance(v, float) and not np.isfinite(v)):
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
        ["3D stage loading", f"{_fmt(s.get('load_s_3d'), ' s', 2)} before the first frame"],
        ["people", f"{people} per frame"],
        ["events", events or "none"],
        ["median reprojection error", _fmt(s.get("reprojection_median_px"), " px")],
    ]
    if s.get("interrupted"):
        rows.append(["interrupted", "yes: the outputs end at the last complete frame"])
    return _table(rows, ["", ""])


def cameras_html(s: dict) -> str:
    rows = []
    for name, c in s.get("per_camera", {}).items():
        src = s.get("sources", {}).get(name, {})
        rows.append([
            name, c.get("frames"), _fmt(c.get("detections_per_frame"), "", 2),
            _fmt(c.get("reprojection_median_px"), " px"),
            _fmt(c.get("reprojection_mean_px"), " px"),
            src.get("dropped", 0), src.get("failures", 0), src.get("reconnects", 0),
        ])  # fmt: skip
    head = ["camera", "frames", "detections/frame", "reprojection median", "reprojection mean",
            "dropped", "failures", "reconnects"]  # fmt: skip
    return _table(rows, head)


def people_html(s: dict) -> str:
    rows = [
        [f"id {p['id']}", p.get("first_frame"), p.get("last_frame"), _fmt(p.get("duration_s")),
         p.get("frames_seen"), _fmt(p.get("path_m"), " m", 2)]
        for p in s.get("people", [])
    ]  # fmt: skip
    return _table(rows, ["person", "first frame", "last frame", "time in view (s)", "frames seen",
                         "path"])  # fmt: skip


CSS = """
body { font-family: system-ui, sans-serif; margin: 1.5em auto; max-width: 1200px; color: #222; }
h1 { font-size: 1.5em; } h2 { font-size: 1.2em; margin-top: 1.6em; }
table { border-collapse: collapse; margin: 0.5em 0; }
td, th { border: 1px solid #ccc; padding: 3px 8px; text-align: left; font-size: 0.9em; }
pre { background: #f6f6f6; padding: 0.8em; overflow-x: auto; font-size: 0.85em; }
"""
