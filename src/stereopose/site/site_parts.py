"""What of `serve` follows the running site: each part told the site at the start and each new
site after (site.site_switch's `on_site`), built here from the site and the service's parts.

- the regions' scans: where workers matter, so the scans plan their tiles on them;
- the carried steps' hazards: the energized zones, dead where the breakers read dead;
- MQTT's retained `site` message: the site's version and zones.

The warnings on site follow it too; they are one of the frame loop's parts (site.run_parts).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Collection
from typing import TYPE_CHECKING

from stereopose.detection.regional import RegionDetector
from stereopose.fence import Site
from stereopose.fence.site import site_version
from stereopose.nodes.fusion import NodeInput
from stereopose.pipeline.sources import Cameras
from stereopose.pipeline.track_regions import watched_shares
from stereopose.site.zone_sources import ZonePower
from stereopose.types import Rig
from stereopose.zones.hazard import Hazards

if TYPE_CHECKING:
    from stereopose.io.sinks.mqtt import MqttSink

__all__ = ["hazards_watch", "mqtt_site", "scans_watch"]


def mqtt_site(mqtt: MqttSink | None, site: Site | None) -> list[Callable[[Site], None]]:
    """The MQTT output's retained `site` message (its version as GET /api/site gives it, its
    zones), now and at each new site; none without an MQTT output or a site."""
    if mqtt is None or site is None:
        return []

    def tell(new: Site) -> None:
        mqtt.set_site(site_version(new), [z.name for z in new.zones], time.time())

    tell(site)
    return [tell]


def hazards_watch(
    cameras: Cameras | NodeInput, power: ZonePower, site: Site | None
) -> Callable[[Site], None]:
    """The carried steps kept away from `site`'s energized zones now and from each new
    site's (zones.hazard): dead where the breakers' points read dead (the service's zone
    states, whichever it has when asked), live otherwise. cameras: this service's own, or
    the nodes' (told which cameras to hold at each step: nodes.hold)."""

    def dead() -> Collection[str]:
        return power.safe_now().keys()

    def watch(new: Site | None) -> None:
        cameras.set_hazards(None if new is None else Hazards(new.zones, dead=dead))

    watch(site)
    return watch


def scans_watch(regions: RegionDetector, rig: Rig, site: Site | None) -> Callable[[Site], None]:
    """The regions' scans told where workers matter, from `site` now and from each new site
    (detection.regional.RegionDetector.watch); the callable takes a new site."""

    def watch(new: Site | None) -> None:
        regions.watch({} if new is None else watched_shares(rig, new.zones))

    watch(site)
    return watch
