"""The report's behaviour section: time in each posture per person (from the 3D poses'
`posture` and `flags`) and the behaviour events (person_down, lone_worker, ...), as HTML."""

from __future__ import annotations

import html
from collections import Counter, defaultdict
from collections.abc import Sequence

import numpy as np

from stereopose.behaviour.definitions import ALARM_TYPES, BEHAVIOUR_KIND
from stereopose.behaviour.posture import FLAGS, POSTURES, UNKNOWN
from stereopose.types import Event

MAX_ROWS = 500  # events listed; the rest counted


def _frame_s(poses: Sequence[tuple[int, float, list[dict]]]) -> float:
    """Seconds per frame of the poses (their times' median step; 1/25 when unknown)."""
    t = np.array([p[1] for p in poses], dtype=float)
    dt = np.diff(t[np.isfinite(t)])
    dt = dt[dt > 0]
    return float(np.median(dt)) if dt.size else 1.0 / 25.0


def postures_html(poses: Sequence[tuple[int, float, list[dict]]]) -> str:
    """Per person: seconds in each posture and with each flag; "" when the poses carry none
    (a run without behaviour rules)."""
    counts: dict[int, Counter] = defaultdict(Counter)
    for _, _, people in poses:
        for p in people:
            posture = p.get("posture")
            if not isinstance(posture, str):
                continue
            c = counts[int(p["id"])]
            c[posture] += 1
            flags = p.get("flags")
            for flag in flags if isinstance(flags, list) else ():
                if flag in FLAGS:
                    c["flag:" + flag] += 1
    if not counts:
        return ""
    step = _frame_s(poses)
    columns = [*POSTURES, UNKNOWN]
    head = "".join(f"<th>{c}</th>" for c in (*columns, *FLAGS))
    rows = []
    for pid in sorted(counts):
        c = counts[pid]
        cells = [c[k] * step for k in columns] + [c["flag:" + f] * step for f in FLAGS]
        rows.append(
            f"<tr><td>{pid}</td>"
            + "".join(f"<td>{v:.1f}</td>" if v else "<td>-</td>" for v in cells)
            + "</tr>"
        )
    return (
        "<p>Seconds in each posture, and with each flag, per person.</p>"
        f"<table><tr><th>id</th>{head}</tr>{''.join(rows)}</table>"
    )


def explain(e: Event) -> str:
    """What explains a behaviour event, in words (its failed conditions, joint, heights,
    distances, speed, duration)."""
    parts = []
    if e.failed:
        parts.append(f"failed: {e.failed}")
    if e.joint:
        parts.append(e.joint)
    if e.height_m is not None:
        parts.append(f"at {e.height_m:.2f} m")
    if e.nearest_m is not None:
        parts.append(f"nearest {e.nearest_m:.1f} m")
    if e.facing_deg is not None:
        parts.append(f"facing {e.facing_deg:.0f} deg")
    if e.speed_m_s is not None:
        parts.append(f"hips dropping {e.speed_m_s:.1f} m/s")
    if e.duration_s is not None:
        parts.append(f"after {e.duration_s:.1f} s")
    if e.lost:
        parts.append("track lost")
    return ", ".join(parts)


def behaviour_events_html(events: Sequence[Event]) -> str:
    """The behaviour events as a table, alarms marked; "" when there are none."""
    rows = [e for e in events if e.kind == BEHAVIOUR_KIND]
    if not rows:
        return ""
    rows.sort(key=lambda e: (e.t, e.person))
    body = []
    for e in rows[:MAX_ROWS]:
        cls = " class='alarm'" if e.type in ALARM_TYPES else ""
        cells = (
            f"{e.t:.2f}",
            f"{e.onset_t:.2f}",
            str(e.person),
            e.type,
            e.rule or "",
            e.zone,
            e.posture or "",
            explain(e),
        )
        body.append(f"<tr{cls}>" + "".join(f"<td>{html.escape(c)}</td>" for c in cells) + "</tr>")
    more = f"<p>{len(rows) - MAX_ROWS} more not listed.</p>" if len(rows) > MAX_ROWS else ""
    head = "".join(
        f"<th>{c}</th>"
        for c in ("t (s)", "since (s)", "id", "event", "rule", "zone", "posture", "why")
    )
    style = "<style>tr.alarm td{color:#b00020}</style>"
    return f"{style}<p>Behaviour events (alarms in red).</p><table><tr>{head}</tr>" + (
        f"{''.join(body)}</table>{more}"
    )
