"""Electronic fences: the site file and the rules that raise events when someone enters or nears
a zone (the zones themselves: stereopose.zones; the events go to the sinks of io.sinks.events)."""

from stereopose.fence.rules import FenceMonitor
from stereopose.fence.site import Site, load_site, save_site
from stereopose.zones import KINDS, Zone, ZoneGeometry

__all__ = ["KINDS", "FenceMonitor", "Site", "Zone", "ZoneGeometry", "load_site", "save_site"]
