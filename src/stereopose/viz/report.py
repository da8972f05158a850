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
from stereopose.fence import Site, load_site
from stereopose.io.results import read_poses
from stereopose.io.sinks.events import read_events
from stereopose.skeleton import LIMBS
from stereopose.types import Event, Rig
from stereopose.viz.colours import id_colour
from stereopose.viz.report_behaviour import behaviour_events_html, explain, postures_html
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
import plotly.graph_objects as go  # noqa: E402
from plotly.offline import get_plotlyjs  # noqa: E402

logger = logging.getLogger(__name__)

MAX_3D_FRAMES = 150
ZONE_COLOURS = {"energized": "#b30000", "restricted": "#e6ab02", "work_area": "#1b9e77"}
EVENT_SYMBOLS = {
    "enter": "triangle-right",
    "exit": "triangle-left",
    "approach": "diamond",
    "dwell": "square",
    "left_work_area": "x",
}


def colour(person_id: int) -> str:
    return id_colour(person_id)  # the console's and the overlays' colour of this id


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


def _zone_prism(zone, name: str) -> go.Mesh3d:
    poly = np.asarray(zone.polygon, float)
    n = len(poly)
    z0, z1 = zone.z
    x = np.concatenate([poly[:, 0], poly[:, 0]])
    y = np.concatenate([poly[:, 1], poly[:, 1]])
    z = np.concatenate([np.full(n, z0), np.full(n, z1)])
    i, j, k = [], [], []
    for a in range(1, n - 1):  # fan triangulation of bottom and top (convex or star-shaped)
        i += [0, n]
        j += [a, n + a]
        k += [a + 1, n + a + 1]
    for a in range(n):
        b = (a + 1) % n
        i += [a, b]
        j += [b, n + b]
        k += [n + a, n + a]
    return go.Mesh3d(
        x=x,
        y=y,
        z=z,
        i=i,
        j=j,
        k=k,
        opacity=0.25,
        color=ZONE_COLOURS.get(zone.kind, "#888"),
        name=f"{name} ({zone.kind})",
        hoverinfo="name",
        showlegend=True,
        flatshading=True,
    )


def _skeleton_xyz(joints: np.ndarray) -> tuple[list, list, list]:
    xs: list = []
    ys: list = []
    zs: list = []
    for a, b in LIMBS:
        if np.isfinite(joints[a]).all() and np.isfinite(joints[b]).all():
            xs += [joints[a, 0], joints[b, 0], None]
            ys += [joints[a, 1], joints[b, 1], None]
            zs += [joints[a, 2], joints[b, 2], None]
    return xs, ys, zs


def figure_3d(poses, rig: Rig, site: Site | None) -> go.Figure:
    """Skeletons over time (a slider and a play button), zones as prisms, cameras, floor."""
    ids = sorted({int(p["id"]) for _, _, people in poses for p in people})
    stride = max(1, int(np.ceil(len(poses) / MAX_3D_FRAMES)))
    shown = poses[::stride]
    static = _static_3d(poses, rig, site)
    # open on the first shown frame with somebody in it
    start = next((i for i, (_, _, people) in enumerate(shown) if people), 0)
    first = shown[start][2] if shown else []
    fig = go.Figure(data=static + _person_traces(first, ids))
    moving = list(range(len(static), len(static) + len(ids)))
    fig.frames = [
        go.Frame(data=_person_traces(people, ids), traces=moving, name=str(frame))
        for frame, _, people in shown
    ]
    _animate(fig, shown, start)
    return fig


def _static_3d(poses, rig: Rig, site: Site | None) -> list:
    """The zones' prisms, the cameras and the floor under everything shown."""
    static: list = []
    if site is not None:
        static += [_zone_prism(z, z.name) for z in site.zones]
    centres = np.array([c.center for c in rig])
    static.append(
        go.Scatter3d(
            x=centres[:, 0],
            y=centres[:, 1],
            z=centres[:, 2],
            mode="markers+text",
            text=list(rig.names),
            marker={"size": 4, "color": "black", "symbol": "diamond"},
            name="cameras",
            textposition="top center",
        )
    )
    pts = np.array([p["joints_array"] for _, _, people in poses for p in people]).reshape(-1, 3)
    pts = pts[np.isfinite(pts).all(axis=1)]
    lo = np.minimum(pts.min(0), centres.min(0)) if len(pts) else centres.min(0)
    hi = np.maximum(pts.max(0), centres.max(0)) if len(pts) else centres.max(0)
    static.append(
        go.Scatter3d(
            x=[lo[0], hi[0], hi[0], lo[0], lo[0]],
            y=[lo[1], lo[1], hi[1], hi[1], lo[1]],
            z=[0] * 5,
            mode="lines",
            line={"color": "#bbbbbb"},
            name="floor (z = 0)",
            hoverinfo="skip",
        )
    )

    return static


def _person_traces(people, ids: list[int]) -> list:
    """One skeleton trace per id (empty for an id not in `people`)."""
    by_id = {int(p["id"]): p for p in people}
    traces = []
    for pid in ids:
        p = by_id.get(pid)
        xs, ys, zs = _skeleton_xyz(p["joints_array"]) if p is not None else ([], [], [])
        traces.append(
            go.Scatter3d(
                x=xs,
                y=ys,
                z=zs,
                mode="lines+markers",
                name=f"id {pid}",
                line={"color": colour(pid), "width": 6},
                marker={"size": 2, "color": colour(pid)},
            )
        )
    return traces


def _animate(fig: go.Figure, shown, start: int) -> None:
    """The frame slider (at `start`) and the play and pause buttons."""
    steps = [
        {
            "method": "animate",
            "label": str(frame),
            "args": [
                [str(frame)],
                {
                    "mode": "immediate",
                    "frame": {"duration": 0, "redraw": True},
                    "transition": {"duration": 0},
                },
            ],
        }
        for frame, _, _ in shown
    ]
    fig.update_layout(
        title="3D skeletons over time (drag to turn, slider for the frame)",
        height=650,
        margin={"l": 0, "r": 0, "t": 40, "b": 0},
        scene={
            "aspectmode": "data",
            "xaxis_title": "x (m)",
            "yaxis_title": "y (m)",
            "zaxis_title": "z (m)",
        },
        sliders=[
            {
                "steps": steps,
                "active": start,
                "currentvalue": {"prefix": "frame "},
                "pad": {"t": 30},
            }
        ],
        updatemenus=[
            {
                "type": "buttons",
                "showactive": False,
                "x": 0.0,
                "y": 1.0,
                "direction": "right",
                "xanchor": "left",
                "yanchor": "top",
                "buttons": [
                    {
                        "label": "play",
                        "method": "animate",
                        "args": [
                            None,
                            {"frame": {"duration": 80, "redraw": True}, "fromcurrent": True},
                        ],
                    },
                    {
                        "label": "pause",
                        "method": "animate",
                        "args": [[None], {"mode": "immediate", "frame": {"duration": 0}}],
                    },
                ],
            }
        ],
    )


def _trajectories(poses) -> dict[int, np.ndarray]:
    tracks: dict[int, list] = {}
    for frame, t, people in poses:
        for p in people:
            pos = p.get("position")
            if pos is not None:
                tracks.setdefault(int(p["id"]), []).append((frame, t, pos[0], pos[1]))
    return {k: np.array(v, float) for k, v in tracks.items()}


def figure_floor(tracks, rig: Rig, site: Site | None, events: list[Event]) -> go.Figure:
    """Top view: zones, cameras with their viewing direction, trajectories, where events were."""
    fig = go.Figure()
    if site is not None:
        for z in site.zones:
            poly = np.vstack([z.polygon, z.polygon[:1]])
            fig.add_trace(
                go.Scatter(
                    x=poly[:, 0],
                    y=poly[:, 1],
                    fill="toself",
                    mode="lines",
                    line={"color": ZONE_COLOURS.get(z.kind, "#888")},
                    opacity=0.35,
                    name=f"{z.name} ({z.kind})",
                )
            )
    for cam in rig:
        c = cam.center
        ahead = c + cam.R[2] * 0.6  # the optical axis, 0.6 m
        fig.add_trace(
            go.Scatter(
                x=[c[0], ahead[0]],
                y=[c[1], ahead[1]],
                mode="lines+markers+text",
                text=[cam.name, ""],
                textposition="top center",
                line={"color": "black"},
                marker={"size": [9, 0], "symbol": "square", "color": "black"},
                showlegend=False,
                hovertext=f"{cam.name}: height {c[2]:.2f} m",
                hoverinfo="text",
            )
        )
    for pid, tr in sorted(tracks.items()):
        fig.add_trace(
            go.Scatter(
                x=tr[:, 2],
                y=tr[:, 3],
                mode="lines",
                name=f"id {pid}",
                line={"color": colour(pid), "width": 3},
                hovertext=[f"id {pid}, frame {int(f)}, t={t:.2f}s" for f, t in tr[:, :2]],
                hoverinfo="text",
            )
        )
        fig.add_trace(
            go.Scatter(
                x=tr[[0, -1], 2],
                y=tr[[0, -1], 3],
                mode="markers",
                showlegend=False,
                marker={"color": colour(pid), "size": 10, "symbol": ["circle-open", "circle"]},
                hovertext=[f"id {pid} first seen", f"id {pid} last seen"],
                hoverinfo="text",
            )
        )
    located = [e for e in events if e.position is not None]
    if located:
        fig.add_trace(
            go.Scatter(
                x=[e.position[0] for e in located],
                y=[e.position[1] for e in located],
                mode="markers",
                name="events",
                marker={
                    "symbol": [EVENT_SYMBOLS.get(e.type, "circle") for e in located],
                    "size": 11,
                    "color": [colour(e.person) for e in located],
                    "line": {"color": "black", "width": 1},
                },
                hovertext=[f"{e.type} {e.zone}, id {e.person}, t={e.t:.2f}s" for e in located],
                hoverinfo="text",
            )
        )
    fig.update_layout(
        title="Floor map: zones, cameras, trajectories (open circle: first seen)",
        height=600,
        xaxis_title="x (m)",
        yaxis_title="y (m)",
        yaxis={"scaleanchor": "x", "scaleratio": 1},
        margin={"t": 40},
    )
    return fig


def figure_timeline(poses, tracks, events: list[Event]) -> go.Figure:
    """Each person's time in view (thin bar), time inside each zone, and every event."""
    fig = go.Figure()
    for pid, tr in sorted(tracks.items()):
        fig.add_trace(
            go.Scatter(
                x=[tr[0, 1], tr[-1, 1]],
                y=[f"id {pid}"] * 2,
                mode="lines",
                line={"color": colour(pid), "width": 3},
                showlegend=False,
                hoverinfo="skip",
            )
        )
    inside: dict[tuple[int, str], float] = {}
    end = max((t for _, t, _ in poses), default=0.0)
    for e in sorted(events, key=lambda e: e.t):
        key = (e.person, e.zone)
        if e.type == "enter":
            inside[key] = e.onset_t if e.onset_t is not None else e.t
        elif e.type == "exit" and key in inside:
            _interval(fig, e.person, e.zone, inside.pop(key), e.t)
    for (pid, zone), t0 in inside.items():
        _interval(fig, pid, zone, t0, end)
    for typ in sorted({e.type for e in events}):
        sel = [e for e in events if e.type == typ]
        fig.add_trace(
            go.Scatter(
                x=[e.t for e in sel],
                y=[f"id {e.person}" for e in sel],
                mode="markers",
                name=typ,
                marker={
                    "symbol": EVENT_SYMBOLS.get(typ, "circle"),
                    "size": 13,
                    "line": {"color": "black", "width": 1},
                },
                hovertext=[_event_text(e) for e in sel],
                hoverinfo="text",
            )
        )
    fig.update_layout(
        title="Event timeline (thick bars: inside a zone)",
        xaxis_title="t (s)",
        height=200 + 40 * len(tracks),
        margin={"t": 40},
    )
    return fig


def _interval(fig: go.Figure, pid: int, zone: str, t0: float, t1: float) -> None:
    fig.add_trace(
        go.Scatter(
            x=[t0, t1],
            y=[f"id {pid}"] * 2,
            mode="lines",
            line={"color": colour(pid), "width": 14},
            opacity=0.5,
            showlegend=False,
            hovertext=f"id {pid} in {zone}: {t0:.2f}-{t1:.2f} s",
            hoverinfo="text",
        )
    )


def _event_text(e: Event) -> str:
    parts = [f"{e.type} {e.zone} ({e.kind})", f"id {e.person}", f"t={e.t:.2f}s"]
    if e.rule is not None:  # a behaviour event: its rule, posture and what explains it
        return ", ".join([*parts, f"rule {e.rule}", e.posture or "", explain(e)])
    if e.joint is not None:
        parts.append(f"joint {e.joint}")
    if e.distance_m is not None:
        parts.append(f"{e.distance_m:.2f} m away")
    if e.duration_s is not None:
        parts.append(f"after {e.duration_s:.1f} s")
    return ", ".join(parts)


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
    tracks = _trajectories(poses)
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
    """Write ``<run_dir>/report.html``; returns its path."""
    path = Path(run_dir) / "report.html"
    text = build_report(run_dir)
    try:
        path.write_text(text, encoding="utf-8")
    except OSError as e:
        raise StereoposeError(f"{path}: cannot write the report: {e.strerror}") from None
    return path
