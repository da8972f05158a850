"""One colour per person id, the same everywhere a person is drawn: the overlays, the console's
camera pictures and alarm clips (viz.overlay), the report (viz.report), and the console's floor
plan and 3D view (site/http/console/colours.js holds the same list; a test keeps them equal).

Tableau 10 without its red: red is the alarm's colour (a person inside an energized zone, an
alarm), so no id is ever drawn in it.
"""

from __future__ import annotations

__all__ = ["ID_COLOURS", "id_colour", "id_colour_bgr"]

ID_COLOURS = (
    "#1f77b4",
    "#ff7f0e",
    "#2ca02c",
    "#9467bd",
    "#8c564b",
    "#e377c2",
    "#17becf",
    "#bcbd22",
    "#7f7f7f",
)


def id_colour(person_id: int) -> str:
    """The person's colour, "#rrggbb" (a negative id counts from the end, as in JavaScript's
    Math.abs: the console uses the absolute value)."""
    return ID_COLOURS[abs(int(person_id)) % len(ID_COLOURS)]


def id_colour_bgr(person_id: int) -> tuple[int, int, int]:
    """The person's colour as OpenCV's (blue, green, red)."""
    h = id_colour(person_id)
    return int(h[5:7], 16), int(h[3:5], 16), int(h[1:3], 16)
