"""What both IEC 104 masters of the zones' state do with an RTU's points, whatever carries the
link (c104's master, scada.iec104_master; the TLS one of our own, scada.iec104_tls): each
point's (common address, IOA) found among the zones' points, its value put on the PowerBoard
(zones.power_state) as the text a zone's expression reads, its quality kept; a point not asked
for, or one not read, counted as refused; a lost link makes every point unknown at once.

Single points are "on" / "off"; double points "open" / "closed" / "intermediate", and
indeterminate (DPI 3) is unknown. `good` is False where the point's quality has a flag set
(invalid, not topical, substituted, blocked).
"""

from __future__ import annotations

from collections.abc import MutableMapping

from stereopose.zones.power import Iec104Point
from stereopose.zones.power_state import PowerBoard

__all__ = ["DOUBLE", "RtuPoints"]

DOUBLE = {0: "intermediate", 1: "open", 2: "closed"}  # a double point's DPI (3: indeterminate)


class RtuPoints:
    """The points of one RTU (host, port) onto `board`, with the link's `figures`."""

    def __init__(
        self,
        host: str,
        port: int,
        points: list[Iec104Point],
        board: PowerBoard,
        figures: MutableMapping[str, int],
    ) -> None:
        self.host, self.port, self.board, self.figures = host, int(port), board, figures
        self.keys = [p.label for p in points]
        self.interrogation_s = min(p.interrogation_s for p in points)
        self.stations = sorted({p.common_address for p in points})
        self._by_point = {(p.common_address, p.ioa): p for p in points}

    def single(self, ca: int, ioa: int, on: bool, good: bool) -> None:
        """A single point's value."""
        p = self._found(ca, ioa)
        if p is not None:
            self.board.set(p.label, "on" if on else "off", good)
            self.figures["iec104_received"] += 1

    def double(self, ca: int, ioa: int, dpi: int, good: bool) -> None:
        """A double point's value (its DPI, 0 to 3)."""
        p = self._found(ca, ioa)
        if p is None:
            return
        text = DOUBLE.get(dpi)
        if text is None:
            self.board.set(p.label, None, False, "double point indeterminate")
        else:
            self.board.set(p.label, text, good)
        self.figures["iec104_received"] += 1

    def refused(self) -> None:
        """A message of the RTU not read: counted, never raised."""
        self.figures["iec104_refused"] += 1

    def lost(self) -> None:
        """The link dropped: every point unknown at once, counted."""
        self.figures["iec104_link_lost"] += 1
        self.board.lost(self.keys, f"IEC 104 link to {self.host}:{self.port} lost")

    def _found(self, ca: int, ioa: int) -> Iec104Point | None:
        p = self._by_point.get((ca, ioa))
        if p is None:
            self.refused()
        return p
