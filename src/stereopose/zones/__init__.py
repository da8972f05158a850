"""Zones of the site plan, low in the stack: a zone (a prism over a floor polygon), its geometry
(inside, distance, near, vectorised), polygons, the approach distances by voltage, and whether an
energized zone is live or dead (its breakers' and earthing switches' points, the expression that
makes it dead, the board of their values and the zones' states). Imports nothing of the fences,
behaviour or tickets that use it."""

from stereopose.zones.geometry import ZoneGeometry
from stereopose.zones.zone import DEFAULT_ENTER_S, DEFAULT_EXIT_S, KINDS, Zone

__all__ = ["DEFAULT_ENTER_S", "DEFAULT_EXIT_S", "KINDS", "Zone", "ZoneGeometry"]
