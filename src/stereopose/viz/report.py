"""The run report: one self-contained HTML page (plotly.js inline, opens offline).

It shows the run summary (frames, speed per stage, people, events), an interactive 3D view of the
skeletons over time with the zones drawn as prisms, a floor map with the cameras, the zones and
each person's trajectory, the event timeline, the behaviour section (time in each posture per
person, the behaviour events) when the site has rules, per-camera statistics and the
configuration used.
``write_report(run_dir)`` rebuilds it from the files of a run folder.
"""

from __future__ import annotations

import html
import json
import logging
import os
import stat
from pathlib import Path

import numpy as np

from stereopose.calibration.formats import load_calibration
from stereopose.config import parse_toml
from stereopose.errors import StereoposeError
from stereopose.extras import require
from stereopose.fence import load_site
from stereopose.io.results import read_poses
from stereopose.io.sinks.events import read_events
from stereopose.tickets.ticket import TICKET_HTML, TICKET_JSON
from stereopose.types import Event
from stereopose.viz.report_behaviour import behaviour_events_html, postures_html
from stereopose.viz.report_figures import (
    figure_3d,
    figure_floor,
    figure_timeline,
    trajectories,
)
from stereopose.viz.report_tables import (
    CSS,
    cameras_html,
    check_summary,
    incidents_html,
    people_html,
    summary_html,
)

# a runtime install has no plotly: say which extra to install, not an ImportError
require("plotly", "report", "the HTML report (report.html)")
from plotly.offline import get_plotlyjs  # noqa: E402

from stereopose.viz.report_ticket import ticket_report, view_from_events  # noqa: E402

logger = logging.getLogger(__name__)


def _load_poses(path: Path) -> tuple[list[tuple[int, float, list[dict]]], int]:
    """The 3D poses of a run and the number of damaged lines skipped (each with a warning): a
    run killed mid-write ends with a cut line, a disk error can damage one in the middle."""
    poses: list[tuple[int, float, list[dict]]] = []
    if not path.is_file():
        return poses, 0
    skipped: list[tuple[int, str]] = []
    try:
        for f, t, people in read_poses(path, skipped=skipped):
            poses.append((f, t if t is not None else np.nan, people))
    except StereoposeError as e:  # the file itself cannot be read
        logger.warning("%s; the report shows the %d frames before it", e, len(poses))
    if skipped:
        logger.warning(
            "%s: %d damaged line(s) skipped (first: line %d); the report shows the %d others",
            path,
            len(skipped),
            skipped[0][0],
            len(poses),
        )
    return poses, len(skipped)


def _load_events(path: Path) -> list[Event]:
    if not path.is_file():
        return []
    try:
        return read_events(path)
    except StereoposeError as e:
        logger.warning("%s; the report shows no events", e)
        return []


def _read_text(path: Path, what: str) -> str:
    """The UTF-8 text of a run file; StereoposeError naming it when it cannot be read."""
    try:
        if not stat.S_ISREG(os.stat(path).st_mode):
            raise StereoposeError(f"{path}: unreadable {what}: not a regular file")
        return path.read_text(encoding="utf-8")
    except OSError as e:
        raise StereoposeError(f"{path}: unreadable {what}: {e.strerror}") from None
    except UnicodeDecodeError as e:
        raise StereoposeError(
            f"{path}: unreadable {what}: not UTF-8 text ({e.reason} at byte {e.start})"
        ) from None


def _load_summary(path: Path) -> dict:
    """summary.json of a run, checked for what the report reads; errors name the file."""
    text = _read_text(path, "run summary")
    try:
        s = json.loads(text)
    except RecursionError:
        raise StereoposeError(f"{path}: unreadable run summary: nested too deeply") from None
    except ValueError as e:  # not JSON, or a number of thousands of digits
        raise StereoposeError(f"{path}: unreadable run summary: {e}") from None
    try:
        check_summary(s)
    except ValueError as e:
        raise StereoposeError(f"{path}: damaged run summary: {e}") from None
    return s


def _load_config(path: Path) -> str:
    """The configuration a run saved, as text ("(not saved)" without one); a damaged one is
    an error naming it and its line."""
    if not path.exists():
        return "(not saved)"
    text = _read_text(path, "configuration")
    parse_toml(text, path)  # a ConfigError naming the file and the line
    return text


def build_report(run_dir: str | Path) -> str:
    """The report of a run folder as one HTML string."""
    run_dir = Path(run_dir)
    summary_path = run_dir / "summary.json"
    if not summary_path.exists():
        raise StereoposeError(f"{run_dir}: not a run folder (no summary.json)")
    s = _load_summary(summary_path)
    config = _load_config(run_dir / "config.toml")
    rig = load_calibration(run_dir / "calib.toml", min_cameras=1)
    site = load_site(run_dir / "site.toml") if (run_dir / "site.toml").is_file() else None
    poses, damaged = _load_poses(run_dir / "poses3d.jsonl")
    events = _load_events(run_dir / "events.jsonl")
    figs = []
    if poses:
        figs.append(("3D view", figure_3d(poses, rig, site), "view3d"))
    tracks = trajectories(poses)
    figs.append(("Floor map", figure_floor(tracks, rig, site, events), "floor"))
    figs.append(("Events", figure_timeline(poses, tracks, events), "timeline"))
    parts = [
        "<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>",
        f"<title>stereopose run: {html.escape(str(run_dir.name))}</title>",
        f"<style>{CSS}</style>",
        f"<script type='text/javascript'>{get_plotlyjs()}</script></head><body>",
        f"<h1>stereopose run <code>{html.escape(str(run_dir))}</code></h1>",
        "<h2>Summary</h2>",
        summary_html(s),
        f"<p>{damaged} damaged line(s) of poses3d.jsonl skipped.</p>" if damaged else "",
        "<h2>People</h2>",
        people_html(s),
    ]
    for title, fig, div in figs:
        parts.append(f"<h2>{title}</h2>")
        if title == "Events" and not events:
            parts.append(
                "<p>No zone events" + (" (no site given)." if site is None else ".") + "</p>"
            )
        parts.append(
            fig.to_html(full_html=False, include_plotlyjs=False, div_id=div, auto_play=False)
        )
    incidents = incidents_html(events)
    if incidents:
        parts += ["<h2>Alarms by incident</h2>", incidents]
    behaviour = postures_html(poses) + behaviour_events_html(events)
    if behaviour:
        parts += ["<h2>Behaviour</h2>", behaviour]
    parts += [
        "<h2>Cameras</h2>",
        cameras_html(s),
        "<h2>Configuration used</h2>",
        f"<pre>{html.escape(config)}</pre>",
        "</body></html>",
    ]
    return "\n".join(parts)


def write_report(run_dir: str | Path) -> Path:
    """Write ``<run_dir>/report.html`` (and ``ticket.html`` when the run followed a ticket,
    ``ticket.json``); returns the report's path."""
    path = Path(run_dir) / "report.html"
    text = build_report(run_dir)
    try:
        path.write_text(text, encoding="utf-8")
    except OSError as e:
        raise StereoposeError(f"{path}: cannot write the report: {e.strerror}") from None
    write_ticket_report(run_dir)
    return path


def write_ticket_report(run_dir: str | Path) -> Path | None:
    """``<run_dir>/ticket.html`` from the run's ticket.json, events and 3D poses; None (and
    an old ticket.html removed) when the run followed no ticket."""
    run_dir = Path(run_dir)
    path, saved = run_dir / TICKET_HTML, run_dir / TICKET_JSON
    if not saved.is_file():
        path.unlink(missing_ok=True)
        return None
    try:
        ticket = json.loads(_read_text(saved, "the run's ticket"))
        if not isinstance(ticket, dict) or not isinstance(ticket.get("steps"), list):
            raise ValueError("not a ticket")
    except ValueError as e:
        raise StereoposeError(f"{saved}: not a ticket: {e}") from None
    records = []
    events_path = run_dir / "events.jsonl"
    if events_path.is_file():
        for line in _read_text(events_path, "the events").splitlines():
            try:
                rec = json.loads(line)
            except ValueError:
                continue  # a damaged line: build_report has said so
            if isinstance(rec, dict):
                records.append(rec)
    site = load_site(run_dir / "site.toml") if (run_dir / "site.toml").is_file() else None
    poses, _ = _load_poses(run_dir / "poses3d.jsonl")
    frames = [
        {"t": t, "people": [{"id": p["id"], "joints": p["joints"]} for p in people]}
        for _, t, people in poses
    ]
    text = ticket_report(
        view_from_events(ticket, records), site.zones if site is not None else (), frames
    )
    try:
        path.write_text(text, encoding="utf-8")
    except OSError as e:
        raise StereoposeError(f"{path}: cannot write the ticket's report: {e.strerror}") from None
    return path
