"""What a site sends its control room, besides the events: the outbox (site.outbox) that sends
the event log over MQTT, made from the service's plan, with the site's plan (its zones and the
console's address, for the control room's page of the site) and its summary at a glance (in
each heartbeat, for the control room's list of sites)."""

from __future__ import annotations

from typing import TYPE_CHECKING

from stereopose.config import Config
from stereopose.fence import Site
from stereopose.site.eventlog import EventLog
from stereopose.site.health.state import ServiceState
from stereopose.site.plan import ServePlan

if TYPE_CHECKING:
    from collections.abc import Callable

    from stereopose.alarms import IncidentRecord
    from stereopose.site.outbox import LogOutbox

__all__ = ["make_outbox", "site_plan", "site_summary"]


def make_outbox(
    plan: ServePlan,
    cfg: Config,
    state: ServiceState,
    acknowledge: Callable[[int, str], IncidentRecord],
) -> LogOutbox:
    """The event log's outbox to the plan's broker (plan.mqtt, which must be set), taking a
    control room's acknowledgements to `acknowledge` (the incident desk's)."""
    from stereopose.site.outbox import LogOutbox, OutboxPace

    if plan.mqtt is None:
        raise ValueError("an outbox needs the plan's MQTT settings")
    return LogOutbox(
        plan.mqtt,
        EventLog(plan.events_db, plan.out_dir / "clips"),
        OutboxPace(resend_s=cfg.mqtt.outbox_resend_s),
        acknowledger=acknowledge,
        summary=lambda: site_summary(state),
        plan=site_plan(plan.site, cfg.serve.public_url or None),
    )


def site_plan(site: Site | None, console_url: str | None) -> dict:
    """The site's zones (name, kind, floor polygon in metres) and console address."""
    zones = (
        []
        if site is None
        else [
            {
                "name": z.name,
                "kind": z.kind,
                "polygon": [[round(float(x), 3), round(float(y), 3)] for x, y in z.polygon],
            }
            for z in site.zones
        ]
    )
    return {"zones": zones, "console_url": console_url}


def site_summary(state: ServiceState) -> dict:
    """The site at a glance: its status, its cameras and those up, the people seen."""
    snap = state.snapshot()
    return {
        "status": snap.status,
        "cameras": len(snap.cameras),
        "cameras_up": sum(1 for c in snap.cameras if c.up),
        "people": snap.people,
    }
