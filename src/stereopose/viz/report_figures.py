"""The run report's figures (plotly): the 3D skeletons over time with the zones as prisms, the
floor map with the cameras, zones and trajectories, the event timeline."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from stereopose.extras import require
from stereopose.fence import Site
from stereopose.skeleton import LIMBS
from stereopose.types import Event, Rig
from stereopose.viz.colours import id_colour
from stereopose.viz.report_behaviour import explain

# a runtime install has no plotly: say which extra to install, not an ImportError
require("plotly", "report", "the HTML report (report.html)")

import plotly.graph_objects as go  # noqa: E402

if TYPE_CHECKING:
    from stereopose.zones.zone import Zone

__all__ = ["colour", "figure_3d", "figure_floor", "figure_timeline", "trajectories"]

# the run's 3D poses as poses3d.jsonl holds them: (frame, t, its people's records)
PoseFrames = list[tuple[int, float, list[dict]]]

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


def _zone_prism(zone: Zone, name: str) -> go.Mesh3d:
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


def figure_3d(poses: PoseFrames, rig: Rig, site: Site | None) -> go.Figure:
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


def _static_3d(poses: PoseFrames, rig: Rig, site: Site | None) -> list:
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


def _person_traces(people: list[dict], ids: list[int]) -> list:
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


def _animate(fig: go.Figure, shown: PoseFrames, start: int) -> None:
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


def trajectories(poses: PoseFrames) -> dict[int, np.ndarray]:
    tracks: dict[int, list] = {}
    for frame, t, people in poses:
        for p in people:
            pos = p.get("position")
            if pos is not None:
                tracks.setdefault(int(p["id"]), []).append((frame, t, pos[0], pos[1]))
    return {k: np.array(v, float) for k, v in tracks.items()}


def figure_floor(
    tracks: dict[int, np.ndarray], rig: Rig, site: Site | None, events: list[Event]
) -> go.Figure:
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
    located = [(e, e.position) for e in events if e.position is not None]
    if located:
        fig.add_trace(
            go.Scatter(
                x=[xy[0] for _, xy in located],
                y=[xy[1] for _, xy in located],
                mode="markers",
                name="events",
                marker={
                    "symbol": [EVENT_SYMBOLS.get(e.type, "circle") for e, _ in located],
                    "size": 11,
                    "color": [colour(e.person) for e, _ in located],
                    "line": {"color": "black", "width": 1},
                },
                hovertext=[f"{e.type} {e.zone}, id {e.person}, t={e.t:.2f}s" for e, _ in located],
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


def figure_timeline(
    poses: PoseFrames, tracks: dict[int, np.ndarray], events: list[Event]
) -> go.Figure:
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
