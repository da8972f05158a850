"""One colour per id everywhere: the console's colours.js holds the list viz.colours gives the
camera pictures, the clips and the report; no id is ever drawn in the alarm's red."""

from __future__ import annotations

import re
from pathlib import Path

from stereopose.viz import colours, overlay, report_figures

CONSOLE = Path(colours.__file__).resolve().parents[1] / "site" / "http" / "console"


def _js_list(name: str) -> list[str]:
    text = (CONSOLE / "colours.js").read_text()
    found = re.search(rf"export const {name} = \[([^\]]*)\]", text, re.S)
    assert found, f"{name} not in colours.js"
    return re.findall(r'"(#[0-9a-fA-F]{6})"', found.group(1))


def test_the_console_draws_each_id_in_the_pictures_colour():
    assert _js_list("ID_COLOURS") == list(colours.ID_COLOURS)
    for pid in (0, 1, 2, 7, 8, 9, 123):
        b, g, r = overlay.colour(pid)
        assert f"#{r:02x}{g:02x}{b:02x}" == colours.id_colour(pid) == report_figures.colour(pid)


def test_ids_never_take_the_alarm_colour():
    alarm = re.search(r'ALARM_COLOUR = "(#[0-9a-fA-F]{6})"', (CONSOLE / "colours.js").read_text())
    assert alarm
    for h in colours.ID_COLOURS:
        r, g, b = (int(h[i : i + 2], 16) for i in (1, 3, 5))
        assert not (r > 180 and g < 90 and b < 90), f"{h} reads as the alarm's red"
    assert len(set(colours.ID_COLOURS)) == len(colours.ID_COLOURS) >= 8
