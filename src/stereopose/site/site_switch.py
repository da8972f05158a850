"""A new site taken by the running service at a step's start (site.site_desk's change).

The step's site is one object (pipeline.incidents.SiteRules: the chain of step rules, the fence
monitor, the alarm settings), built by `site_rules` from a site, at the start and at each
change. A change builds the new site's whole, between two steps, and the incident step takes it
in place of the old: the fences, the behaviour rules, the zones' states, the tickets' zones,
the incidents' priorities and the console's scene all on the new site from this step, the
people's tracks untouched (the 3D stage never sees a site). What outlives a site is declared:
the fences' debounce state and the zones switched off (carried by the new fence monitor from
the old: fence.rules), the open incidents (the book), and the parts in `Outliving`.

Who is inside or near a zone kept as it was stays so (no event of the change's own); a person
inside a removed zone gets an `exit` (source "site changed"), which ends its incident; a
`site_changed` event (kind "service", information) says who changed the site and what: the
zones added, removed and changed, and the new version. The zones' state sources are started
again only when a zone's state source changed.
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from stereopose.alarms.priority import AlarmSettings
from stereopose.config import Config
from stereopose.fence import FenceMonitor, Site
from stereopose.onsite.service import OnSite
from stereopose.pipeline.incidents import SiteRules
from stereopose.pipeline.loop import behaviour_monitor
from stereopose.pipeline.step_rules import step_chain
from stereopose.site.scene import SceneState
from stereopose.site.site_desk import SiteChange, SiteDesk
from stereopose.site.steps import HeldFences, HeldRules, ServeEvents
from stereopose.tickets import TicketDesk
from stereopose.types import Event
from stereopose.zones.power_state import ZoneStates

__all__ = ["Outliving", "SiteSwitch", "site_changes", "site_rules"]

logger = logging.getLogger(__name__)


def site_changes(old: Site, new: Site) -> tuple[list[str], list[str], list[str]]:
    """(added, removed, changed) zone names from `old` to `new`."""
    before = {z.name: z for z in old.zones}
    after = {z.name: z for z in new.zones}
    added = [n for n in after if n not in before]
    removed = [n for n in before if n not in after]
    changed = [n for n in after if n in before and not after[n].same_as(before[n])]
    return added, removed, changed


@dataclass
class Outliving:
    """The step chain's parts that outlive a site, in each new site's chain: the tickets'
    desk (told the new zones), the zones' states from their breakers (restarted when a
    zone's state source changed), the warnings on site (built again by an `on_site`)."""

    tickets: TicketDesk | None = None
    zone_state: ZoneStates | None = None
    onsite: OnSite | None = None


def site_rules(
    site: Site | None,
    events: ServeEvents,
    config: Config,
    kept: Outliving,
    monitor: FenceMonitor | None = None,
) -> SiteRules:
    """The service's step rules on `site` (None: no site): the service's opening events, the
    site's fences on the people's time (`monitor`, or a new one), the service's own events,
    the behaviour rules, the zones' states, the tickets and the warnings on site (the kept
    parts), and the site's alarm settings."""
    if monitor is None and site is not None:
        monitor = FenceMonitor(site, config.fps, config.tracking.max_lost_s)
    behaviour = behaviour_monitor(site, config)
    chain = step_chain(
        HeldFences(monitor, events.time) if monitor is not None else None,
        service=events,
        behaviour=HeldRules(behaviour, events.time) if behaviour is not None else None,
        zone_state=kept.zone_state,
        monitor=monitor,
        tickets=kept.tickets,
        onsite=kept.onsite,
    )
    settings = AlarmSettings.from_site(site) if site is not None else AlarmSettings()
    return SiteRules(chain, monitor, settings)


class SiteSwitch:
    """See the module: `switch(rules, t, frame)` (pipeline.incidents.SiteSwitching) gives the
    events of the step's changes and the new site's rules (None: no new site); `rules(site)`
    the step's rules on a site, as each change builds them. desk: where changes come from
    (None: the site never changes, and a step takes none). restart_power(site): the
    service's zone-state sources made the new site's; returns its ZoneStates (None: no zone
    with a state source)."""

    def __init__(
        self,
        desk: SiteDesk | None,
        events: ServeEvents,
        config: Config,
        *,
        kept: Outliving | None = None,
        restart_power: Callable[[Site], ZoneStates | None] | None = None,
        scene: SceneState | None = None,
        on_site: Sequence[Callable[[Site], None]] = (),
    ) -> None:
        self.desk, self.events, self.config = desk, events, config
        self.kept = kept or Outliving()
        self.restart_power, self.scene = restart_power, scene
        self.on_site = tuple(on_site)  # told each new site (the regions' scans)

    def rules(self, site: Site | None, monitor: FenceMonitor | None = None) -> SiteRules:
        """The step's rules on `site` (site_rules, with the parts kept across sites)."""
        return site_rules(site, self.events, self.config, self.kept, monitor)

    def __call__(
        self, rules: SiteRules, t: float, frame: int
    ) -> tuple[list[Event], SiteRules | None]:
        desk = self.desk
        if desk is None:
            return [], None
        notes = [_service_event(t, frame, kind, text) for kind, text in desk.take_notes()]
        change = desk.take()
        taken = None
        if change is not None:
            try:
                found, taken = self._switch(rules.holding, change, t, frame)
            except Exception:  # a change half-taken would leave the site unwatched: said loudly
                logger.exception("site: version %s could not be taken", change.version)
                raise
            notes += found
        fences = taken.holding if taken is not None else rules.holding
        return notes + self._zones_switched(desk, fences, t, frame), taken

    def _zones_switched(
        self, desk: SiteDesk, fences: FenceMonitor | None, t: float, frame: int
    ) -> list[Event]:
        """The zones switched off or on since the last step (SiteDesk.switch_zone): for one
        switched off, an exit for each person in it (its incident ends) and `zone_disabled`;
        for one switched on, `zone_enabled` (people in it enter after its debounce)."""
        out: list[Event] = []
        for zone, on, by in desk.take_switches():
            if fences is None:
                break
            exits = [] if on else _exits(fences, [zone], t, frame, f"zone switched off by {by}")
            if fences.switch(zone, on):
                out += exits
                kind = "zone_enabled" if on else "zone_disabled"
                text = f"{by}: {zone} switched {'on' if on else 'off'}"
                logger.warning("site: %s", text)
                out.append(dataclasses.replace(_service_event(t, frame, kind, text), zone=zone))
        return out

    def _switch(
        self, old_mon: FenceMonitor | None, change: SiteChange, t: float, frame: int
    ) -> tuple[list[Event], SiteRules]:
        cfg = self.config
        new_mon = FenceMonitor(change.new, cfg.fps, cfg.tracking.max_lost_s)
        out: list[Event] = []
        added, removed, changed = site_changes(change.old, change.new)
        if old_mon is not None:
            new_mon.carry(old_mon)
            out += _exits(old_mon, removed, t, frame)
        kept = self.kept
        if kept.tickets is not None:
            kept.tickets.set_zones(change.new.zones)
        if self.restart_power is not None and _power_changed(change.old, change.new):
            kept.zone_state = self.restart_power(change.new)
        rules = self.rules(change.new, new_mon)
        if self.scene is not None:
            self.scene.set_site(change.new)
        for tell in self.on_site:  # what only follows the site: a failure does not undo it
            try:
                tell(change.new)
            except Exception:
                logger.exception("site: version %s not told to %r", change.version, tell)
        said = "; ".join(
            f"{what} {', '.join(names)}"
            for what, names in (("added", added), ("removed", removed), ("changed", changed))
            if names
        )
        text = f"{change.by}: version {change.version}" + (f"; zones {said}" if said else "")
        logger.info("site: taken at frame %d (%s)", frame, text)
        out.append(_service_event(t, frame, "site_changed", text))
        return out, rules


def _service_event(t: float, frame: int, type_: str, text: str) -> Event:
    return Event(
        t=t, frame=frame, person=-1, zone="", kind="service", type=type_, onset_t=t, source=text
    )


def _exits(
    old: FenceMonitor,
    removed: list[str],
    t: float,
    frame: int,
    why: str = "site changed: zone removed",
) -> list[Event]:
    """An exit for each person inside a removed (or switched off) zone: its incident ends."""
    out = []
    kinds = {z.name: z.kind for z in old.zones}
    for name in removed:
        inside, _ = old.occupants(name)
        for pid, _ in inside:
            out.append(
                Event(
                    t=t,
                    frame=frame,
                    person=int(pid),
                    zone=name,
                    kind=kinds[name],
                    type="exit",
                    onset_t=t,
                    source=why,
                )
            )
    return out


def _power_changed(old: Site, new: Site) -> bool:
    def sources(site: Site) -> dict[str, dict]:
        return {z.name: z.power.to_toml() for z in site.zones if z.power is not None}

    return sources(old) != sources(new)
