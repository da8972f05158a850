"""What of `serve` follows the running site: each part told the site at the start and each new
site after (site.site_switch's `on_site`), built here from the site and the service's parts.

- the regions' scans: where workers matter, so the scans plan their tiles on them;
- the carried steps' hazards: the energized zones, dead where the breakers read dead;
- MQTT's retained `site` message: the site's version and zones;
- the warnings on site (onsite): the speakers and signals of its `[warnings]`.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Collection

from stereopose.detection.regional import RegionDetector
from stereopose.fence import Site
from stereopose.fence.site import site_version
from stereopose.io.sinks.base import unwrapped
from stereopose.nodes.fusion import NodeInput
from stereopose.onsite.service import OnSite
from stereopose.pipeline.sources import Cameras
from stereopose.pipeline.track_regions import watched_shares
from stereopose.site.plan import ServePlan
from stereopose.site.service import SiteService
from stereopose.types import Rig
from stereopose.zones.hazard import Hazards

__all__ = ["hazards_watch", "mqtt_site", "onsite_warnings", "scans_watch"]

logger = logging.getLogger(__name__)


def onsite_warnings(plan: ServePlan, service: SiteService, sinks: list) -> OnSite | None:
    """The warnings on site of the site's `[warnings]` (onsite; None without a site): said
    and shown where a hazard's zone is not safe now (dead by its breakers, isolated by the
    running ticket), told on MQTT's `warnings`."""
    if plan.site is None:
        return None
    from stereopose.io.sinks.mqtt import MqttSink

    mqtt = next((u for s in sinks if isinstance(u := unwrapped(s), MqttSink)), None)

    def safe() -> set[str]:
        out: set[str] = set()
        for judge in (service.power, service.tickets):
            if judge is not None:
                out |= set(judge.safe_now())
        return out

    onsite = OnSite(plan.site, safe=safe, publish=mqtt.set_warnings if mqtt else None)
    service.warn_on_site(onsite)  # the API's, and closed with the service
    if onsite.warner is not None:
        w = onsite.warner
        speakers, signals = len(w.speakers), len(w.signals)
        logger.info("warnings on site: %d speaker(s), %d signal(s)", speakers, signals)
    return onsite


def mqtt_site(sinks: list, site: Site | None) -> list[Callable[[Site], None]]:
    """The MQTT output's retained `site` message (its version as GET /api/site gives it, its
    zones), now and at each new site; none without an MQTT output or a site."""
    from stereopose.io.sinks.mqtt import MqttSink

    mqtt = next((u for s in sinks if isinstance(u := unwrapped(s), MqttSink)), None)
    if mqtt is None or site is None:
        return []

    def tell(new: Site) -> None:
        mqtt.set_site(site_version(new), [z.name for z in new.zones], time.time())

    tell(site)
    return [tell]


def hazards_watch(
    cameras: Cameras | NodeInput, service: SiteService, site: Site | None
) -> Callable[[Site], None]:
    """The carried steps kept away from `site`'s energized zones now and from each new
    site's (zones.hazard): dead where the breakers' points read dead (the service's zone
    states, whichever it has when asked), live otherwise. cameras: this service's own, or
    the nodes' (told which cameras to hold at each step: nodes.hold)."""

    def dead() -> Collection[str]:
        states = service.power
        return () if states is None else states.safe_now().keys()

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
