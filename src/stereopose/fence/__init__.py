"""Electronic fences: zones on the site plan and the rules that raise events (the events go to
the sinks of io.sinks.events)."""

from stereopose.fence.rules import FenceMonitor
from stereopose.fence.zones import KINDS, Site, Zone, ZoneGeometry, load_site, save_site

__all__ = ["KINDS", "FenceMonitor", "Site", "Zone", "ZoneGeometry", "load_site", "save_site"]
