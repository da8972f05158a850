"""The frame loop's own parts under `serve`, made once its sinks are open (site.run_sinks), in
their start order: the calibration keeper (attached to the API's desk), the event log's outbox
to a control room, the warnings on site (attached to the API's desk), the receivers' watchdog
(the nodes' MQTT client, the outbox's sender: started again should one die). They start once
the loop's incident step is about to run and close in the mirror order when the loop ends,
before the service's standing parts (site.service); each is registered with the service's
report when made."""

from __future__ import annotations

import functools
import logging
from typing import TYPE_CHECKING

from stereopose.config import Config
from stereopose.onsite.service import OnSite
from stereopose.site.feed import make_outbox
from stereopose.site.health.calib_keeper import CalibrationKeeper
from stereopose.site.health.watchdog import Watchdog
from stereopose.site.lifecycle import Part, Parts, running
from stereopose.site.run_sinks import RunSinks
from stereopose.site.service import SiteService

if TYPE_CHECKING:
    from collections.abc import Callable

    from stereopose.io.sinks.mqtt import MqttSink
    from stereopose.nodes.fusion import NodeInput
    from stereopose.site.outbox import LogOutbox

__all__ = ["RunParts", "onsite_warnings"]

logger = logging.getLogger(__name__)


class RunParts:
    """See the module. nodes: the detection nodes' input (None: this process detects)."""

    def __init__(
        self,
        service: SiteService,
        cfg: Config,
        sinks: RunSinks,
        keeper: CalibrationKeeper,
        nodes: NodeInput | None,
    ) -> None:
        plan = service.plan
        self.onsite = onsite_warnings(service, sinks.mqtt)
        try:
            self.outbox = (
                make_outbox(plan, cfg, service.report.state, service.desk.acknowledge)
                if plan.mqtt is not None and cfg.mqtt.outbox
                else None
            )
        except BaseException:
            if self.onsite is not None:
                self.onsite.close()
            raise
        receivers: dict[str, Callable[[], object]] = {}
        if nodes is not None:
            receivers["nodes"] = nodes.ensure_running
        if self.outbox is not None:
            receivers["outbox"] = self.outbox.ensure_running
        self.watchdog = Watchdog(parts=receivers)
        _watch(service, keeper, self.outbox, self.onsite)
        self.parts = Parts(self._order(service, sinks, keeper))

    def _order(
        self, service: SiteService, sinks: RunSinks, keeper: CalibrationKeeper
    ) -> list[Part]:
        desk, warnings = service.calibration_desk, service.warnings
        onsite, outbox = self.onsite, self.outbox

        def close_keeper() -> None:
            desk.detach()
            keeper.close()

        parts = [
            Part("the calibration keeper", functools.partial(desk.attach, keeper), close_keeper)
        ]
        if outbox is not None:

            def close_outbox() -> None:
                outbox.close()  # sends what the log holds: status.json counts it
                sinks.status.write_now()

            parts.append(running("the outbox", close_outbox))  # its sender runs from when made
        if onsite is not None:

            def close_onsite() -> None:  # every speaker quiet, every coil off
                warnings.detach()
                onsite.close()

            parts.append(
                Part("the warnings on site", lambda: warnings.attach(onsite), close_onsite)
            )
        # stopped before the parts it watches
        parts.append(Part("the watchdog", self.watchdog.start, self.watchdog.stop))
        return parts


def _watch(
    service: SiteService,
    keeper: CalibrationKeeper,
    outbox: LogOutbox | None,
    onsite: OnSite | None,
) -> None:
    """The run's parts in status.json and the health state."""
    report = service.report
    report.watch("calibration", keeper.figures)
    if outbox is not None:
        report.watch("outbox", outbox.figures)
        report.state.register_output("outbox", outbox.health)
    if onsite is not None:
        report.watch("warnings_on_site", onsite.figures)


def onsite_warnings(service: SiteService, mqtt: MqttSink | None) -> OnSite | None:
    """The warnings on site of the site's `[warnings]` (onsite; None without a site): said
    and shown where a hazard's zone is not safe now (dead by its breakers, isolated by the
    running ticket), told on MQTT's `warnings`."""
    site = service.plan.site
    if site is None:
        return None
    power, tickets = service.power, service.tickets

    def safe() -> set[str]:
        out = set(power.safe_now())
        if tickets is not None:
            out |= set(tickets.safe_now())
        return out

    onsite = OnSite(site, safe=safe, publish=mqtt.set_warnings if mqtt else None)
    if onsite.warner is not None:
        w = onsite.warner
        speakers, signals = len(w.speakers), len(w.signals)
        logger.info("warnings on site: %d speaker(s), %d signal(s)", speakers, signals)
    return onsite
