"""A ticket's report: one self-contained HTML page (plotly.js inline, opens offline) with the
ticket, who did it, its steps on a timeline with each step's time, duration, position and order,
its deviations, its result, and a 3D replay of the job (slider and play button) with the zones
drawn and the steps' positions and targets marked.

`ticket_report(view, zones, frames)` takes the ticket as the desk shows it
(tickets.TicketDesk.ticket, or `view_from_events` for a run's events.jsonl), the site's zones
and the job's frames as site.replay gives them ({"wall_t" or "t", "people": [{"id",
"joints"}]}). Times are shown as UTC dates where the view has wall times, else as the run's
seconds.
"""

from __future__ import annotations

import html
from collections.abc import Iterable, Sequence
from datetime import UTC, datetime
from typing import TYPE_CHECKING, Any

import numpy as np

from stereopose.types import JsonDoc
from stereopose.viz.report_figures import _animate, _person_traces, _zone_prism, go
from stereopose.viz.report_tables import CSS

if TYPE_CHECKING:
    from stereopose.zones.zone import Zone

__all__ = ["MAX_REPORT_FRAMES", "ticket_report", "view_from_events"]

MAX_REPORT_FRAMES = 400
_DEVIATIONS = (
    "step_out_of_order",
    "step_wrong_position",
    "step_timeout",
    "supervisor_absent",
    "lone_in_room",
)
_E = html.escape


def _when(wall: float | None, t: float | None) -> str:
    if isinstance(wall, (int, float)):
        return datetime.fromtimestamp(wall, UTC).strftime("%Y-%m-%d %H:%M:%S UTC")
    return f"t = {t:.2f} s" if isinstance(t, (int, float)) else "-"


def view_from_events(ticket: JsonDoc, events: Iterable[JsonDoc]) -> dict:
    """A ticket's view (as TicketDesk.ticket gives it) from its events (event records, as in
    events.jsonl): the steps done, the deviations and the result."""
    tid = ticket["id"]
    events = list(events)
    mine = [e for e in events if e.get("ticket") == tid]
    steps = {
        s["name"]: {
            "name": s["name"],
            "position": s["position"],
            "target": s["target"],
            "optional": bool(s.get("optional", False)),
            "state": "open",
            "done_t": None,
            "onset_t": None,
            "by": None,
            "in_order": None,
            "failed": None,
            "where": None,
        }
        for s in ticket["steps"]
    }
    deviations: list[dict[str, object]] = []
    view: dict[str, object] = {
        **{k: ticket.get(k) for k in ("id", "title", "kind")},
        "isolated": list(ticket.get("isolated", [])),
        "state": "active",
        "operator": None,
        "supervisor": None,
        "started_t": None,
        "ended_t": None,
        "started_by": None,
        "ended_by": None,
        "ticket": dict(ticket),
        "deviation_list": deviations,
        "result": None,
    }
    for e in mine:
        kind, s = e.get("type"), steps.get(e.get("step") or "")
        if kind == "ticket_started":
            view["started_t"] = e.get("t")
        elif kind == "step_done" and s is not None:
            s |= {"state": "done", "done_t": e.get("t"), "onset_t": e.get("onset_t")}
            s |= {"by": e.get("person"), "where": e.get("position")}
            s["in_order"] = s["in_order"] is not False
        elif kind == "step_out_of_order" and s is not None:
            s["in_order"] = False
        elif kind == "step_wrong_position" and s is not None:
            s["failed"] = e.get("failed")
        elif kind == "step_timeout" and s is not None and s["state"] != "done":
            s["state"] = "timed_out"
        elif kind == "ticket_completed":
            view["ended_t"], view["result"] = e.get("t"), e.get("result")
            r = e.get("result") or {}
            view["state"] = "aborted" if r.get("aborted") else "completed"
            view["operator"], view["supervisor"] = r.get("operator"), r.get("supervisor")
        if kind in _DEVIATIONS:
            deviations.append({"type": kind, "t": e.get("t"), "step": e.get("step")})
    view["steps"] = list(steps.values())
    view["zone_states"] = [  # the energized zones' states the job was judged with
        {"t": e.get("t"), "zone": e.get("zone"), "state": e["type"][5:], "source": e.get("source")}
        for e in events
        if e.get("type") in ("zone_live", "zone_dead", "zone_unknown")
    ]
    return view


def _timeline(view: JsonDoc) -> str:
    """An SVG bar per step from its action's onset to its completion over the job's span."""
    t0, t1 = view.get("started_t"), view.get("ended_t")
    done = [s for s in view["steps"] if s.get("done_t") is not None]
    if t0 is None:
        return ""
    if t1 is None:
        t1 = max([s["done_t"] for s in done], default=t0)
    span = max(t1 - t0, 1e-6)
    rows = []
    for k, s in enumerate(view["steps"]):
        y = 8 + 22 * k
        label = f"{k + 1}. {s['name']}"
        rows.append(f"<text x='0' y='{y + 12}' font-size='12'>{_E(label[:40])}</text>")
        if s.get("done_t") is None:
            continue
        a = 300 + 600 * max(0.0, (s.get("onset_t", s["done_t"]) - t0) / span)
        b = 300 + 600 * min(1.0, (s["done_t"] - t0) / span)
        colour = "#2e7d32" if s.get("in_order") is not False and not s.get("failed") else "#e65100"
        rows.append(
            f"<rect x='{a:.1f}' y='{y}' width='{max(b - a, 3):.1f}' height='16' fill='{colour}'>"
            f"<title>{_E(s['name'])}</title></rect>"
        )
    for d in view.get("deviation_list", []):
        if d.get("t") is None:
            continue
        x = 300 + 600 * min(1.0, max(0.0, (d["t"] - t0) / span))
        rows.append(
            f"<line x1='{x:.1f}' x2='{x:.1f}' y1='0' y2='{22 * len(view['steps']) + 8}' "
            f"stroke='#c62828' stroke-dasharray='3,2'><title>{_E(d['type'])}</title></line>"
        )
    height = 22 * len(view["steps"]) + 30
    axis = (
        f"<text x='300' y='{height - 4}' font-size='11'>start</text>"
        f"<text x='900' y='{height - 4}' font-size='11' text-anchor='end'>"
        f"end (+{span:.1f} s)</text>"
    )
    return f"<svg width='920' height='{height}' role='img'>{''.join(rows)}{axis}</svg>"


def _steps_table(view: JsonDoc, wall0: float | None) -> str:
    head = (
        "<tr><th>#</th><th>step</th><th>position</th><th>target</th><th>state</th>"
        "<th>done</th><th>held</th><th>by</th><th>in order</th><th>wrong</th><th>stood at</th></tr>"
    )
    rows = []
    for k, s in enumerate(view["steps"]):
        held = (
            f"{s['done_t'] - s['onset_t']:.2f} s"
            if s.get("done_t") is not None and s.get("onset_t") is not None
            else ""
        )
        where = ", ".join(f"{v:.2f}" for v in s["where"]) if s.get("where") else ""
        wall = wall0 + s["done_t"] if wall0 is not None and s.get("done_t") is not None else None
        cells = [
            str(k + 1),
            s["name"] + (" (optional)" if s.get("optional") else ""),
            s["position"],
            s["target"],
            s["state"],
            _when(wall, s.get("done_t")) if s.get("done_t") is not None else "",
            held,
            f"id {s['by']}" if s.get("by") is not None else "",
            {True: "yes", False: "no"}.get(s.get("in_order"), ""),
            s.get("failed") or "",
            f"({where}) m" if where else "",
        ]
        rows.append("<tr>" + "".join(f"<td>{_E(str(c))}</td>" for c in cells) + "</tr>")
    return f"<table>{head}{''.join(rows)}</table>"


def _figure(frames: Sequence[JsonDoc], zones: Sequence[Zone], marked: set[str]) -> go.Figure | None:
    poses = []
    stride = max(1, int(np.ceil(len(frames) / MAX_REPORT_FRAMES)))
    for k, f in enumerate(frames[::stride]):
        people = []
        for p in f.get("people", []):
            joints = np.array(
                [j if j is not None else [np.nan] * 3 for j in (p.get("joints") or [])], float
            ).reshape(-1, 3)
            if len(joints) == 17:
                people.append({"id": p.get("id"), "joints_array": joints})
        poses.append((k, f.get("wall_t", f.get("t")), people))
    ids = sorted({int(p["id"]) for _, _, people in poses for p in people})
    if not ids:
        return None
    static = [_zone_prism(z, z.name + (" (step)" if z.name in marked else "")) for z in zones]
    start = next((i for i, (_, _, people) in enumerate(poses) if people), 0)
    fig = go.Figure(data=static + _person_traces(poses[start][2], ids))
    moving = list(range(len(static), len(static) + len(ids)))
    fig.frames = [
        go.Frame(data=_person_traces(people, ids), traces=moving, name=str(k))
        for k, _, people in poses
    ]
    _animate(fig, poses, start)
    fig.update_layout(title="The job in 3D (drag to turn, slider to scrub, play)")
    return fig


def _states_used(changes: Sequence[JsonDoc]) -> str:
    """Which energized zones' states the job was judged with, in one line."""
    if not changes:
        return "none known: every energized zone taken as live"
    return "; ".join(
        f"{c.get('zone')} {c.get('state')} at {float(c.get('t') or 0.0):.1f} s"
        + (f" ({c['source']})" if c.get("source") else "")
        for c in changes
    )


def ticket_report(
    view: JsonDoc,
    zones: Sequence[Any],
    frames: Sequence[JsonDoc] = (),
    wall_start: float | None = None,
) -> str:
    """The report (see the module) as one HTML string. wall_start: the Unix time of the
    view's t = 0 (None: times shown as t)."""
    from plotly.offline import get_plotlyjs

    tid = str(view.get("id", ""))
    wall = (lambda t: wall_start + t if t is not None else None) if wall_start else None
    started = _when(wall(view.get("started_t")) if wall else None, view.get("started_t"))
    ended = _when(wall(view.get("ended_t")) if wall else None, view.get("ended_t"))
    facts = [
        ("ticket", tid),
        ("title", view.get("title") or ""),
        ("kind", view.get("kind") or ""),
        ("state", view.get("state") or ""),
        ("started", started + (f" by {view['started_by']}" if view.get("started_by") else "")),
        ("ended", ended + (f" by {view['ended_by']}" if view.get("ended_by") else "")),
        ("operator", f"id {view['operator']}" if view.get("operator") is not None else "unbound"),
        (
            "supervisor",
            f"id {view['supervisor']}" if view.get("supervisor") is not None else "unbound",
        ),
        ("isolated", ", ".join(view.get("isolated") or []) or "none"),
        ("zone states", _states_used(view.get("zone_states") or [])),
    ]
    parts = [
        "<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>",
        f"<title>stereopose ticket {_E(tid)}</title><style>{CSS}</style>",
        f"<script type='text/javascript'>{get_plotlyjs()}</script></head><body>",
        f"<h1>Ticket <code>{_E(tid)}</code>: {_E(str(view.get('title') or ''))}</h1>",
        "<table>"
        + "".join(f"<tr><th>{_E(k)}</th><td>{_E(str(v))}</td></tr>" for k, v in facts)
        + "</table>",
    ]
    r = view.get("result")
    if r:
        parts.append(
            f"<h2>Result</h2><p>{len(r.get('done', []))} of {r.get('steps')} steps done, "
            f"{len(r.get('done_in_order', []))} in order; missed: "
            f"{_E(', '.join(r.get('missed', [])) or 'none')}; deviations: "
            f"{r.get('deviations', 0)}{' (aborted)' if r.get('aborted') else ''}.</p>"
        )
    parts += ["<h2>Steps</h2>", _timeline(view), _steps_table(view, wall_start)]
    devs = view.get("deviation_list") or []
    parts.append("<h2>Deviations</h2>")
    if devs:
        rows = "".join(
            f"<tr><td>{_E(_when(wall(d.get('t')) if wall else None, d.get('t')))}</td>"
            f"<td>{_E(d['type'])}</td><td>{_E(d.get('step') or '')}</td></tr>"
            for d in devs
        )
        parts.append(f"<table><tr><th>when</th><th>deviation</th><th>step</th></tr>{rows}</table>")
    else:
        parts.append("<p>None.</p>")
    marked = {z for s in view["steps"] for z in (s["position"], s["target"])}
    fig = _figure(frames, zones, marked)
    parts.append("<h2>3D replay</h2>")
    if fig is None:
        parts.append("<p>No 3D poses of the job are stored.</p>")
    else:
        parts.append(
            fig.to_html(full_html=False, include_plotlyjs=False, div_id="replay", auto_play=False)
        )
    parts.append("</body></html>")
    return "\n".join(parts)
