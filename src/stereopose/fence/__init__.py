"""Electronic fences: zones on the site plan, rules that raise events, and event sinks."""

from stereopose.fence.rules import FenceMonitor
from stereopose.fence.zones import KINDS, Site, Zone, ZoneGeometry, load_site, save_site

__all__ = ["KINDS", "FenceMonitor", "Site", "Zone", "ZoneGeometry", "load_site", "save_site"]
