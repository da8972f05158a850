"""The site service's standing parts, each made with what it needs by `SiteService`'s
constructor (serve's builder: site.serve calls it once) and started in one ordered list
(site.lifecycle): the HTTP server with the console's API, the console's live channel, the OPC UA
server, the site desk, the storage maintainer, the zones' state sources. `close()` closes them in
the mirror order. Nothing is set on the service once it is built (`__setattr__` refuses).

The frame loop's own parts, made once the cameras are open (its sinks and alarm outputs, the
outbox, the calibration keeper, the warnings on site, the receivers' watchdog), are built by
site.run_parts over the service. What the service reports about itself (the health state, each
part's figures, `status.json`) is its `report` (site.report)."""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import TYPE_CHECKING

from stereopose.errors import StereoposeError
from stereopose.fence import Site
from stereopose.io.source import Clock
from stereopose.io.writing import make_folder
from stereopose.site.desk import IncidentDesk
from stereopose.site.eventlog import EventLog
from stereopose.site.health.calib_keeper import KeeperDesk
from stereopose.site.health.state import ServiceState
from stereopose.site.http.api.warnings import WarningsDesk
from stereopose.site.http.app import Desks, create_app
from stereopose.site.http.web import Console
from stereopose.site.lifecycle import Part, Parts, nothing
from stereopose.site.live import LiveHub
from stereopose.site.plan import ServePlan, packet_rings
from stereopose.site.report import StatusReport
from stereopose.site.restart import Resume
from stereopose.site.site_desk import SiteDesk
from stereopose.site.storage import StorageMaintainer
from stereopose.site.zone_sources import ZonePower
from stereopose.tickets import TicketDesk
from stereopose.web.hosts import allowed_hosts
from stereopose.web.server import Server

if TYPE_CHECKING:
    from stereopose.scada.opcua import OpcuaServer
    from stereopose.scada.opcua_settings import OpcuaSettings
    from stereopose.types import Rig

__all__ = ["SiteService"]

logger = logging.getLogger(__name__)


class SiteService:
    """See the module. Built once from a checked plan; `start()` once, `close()` once."""

    def __init__(
        self,
        plan: ServePlan,
        resume: Resume,
        opcua: OpcuaSettings | None = None,
    ) -> None:
        """opcua: [opcua] checked (scada.opcua_settings; None: off)."""
        p = plan
        self.plan, self.resume = plan, resume
        self.clock = Clock.now()  # the service's t = 0: its steps' and events' times
        # the health state, the outputs that failed, each part's figures: status.json
        self.report = StatusReport(
            ServiceState(p.rig.names, camera_timeout_s=p.config.serve.camera_timeout_s)
        )
        self.packets = packet_rings(p)
        self.desk = IncidentDesk()  # the app's way to the incident book, attached once it runs
        self.tickets = _tickets(p, self.clock.start_epoch)  # none without a site
        # the energized zones' live or dead state from the utility (zones.power_state)
        self.power = ZonePower(p.site, mqtt=p.mqtt, base=p.config_path.resolve().parent)
        # the site edited while serving (GET/PUT /api/site, SIGHUP): taken at a step's start
        self.site_desk = _site_desk(p, self._check_site)
        self.warnings = WarningsDesk()  # the API's way to the warnings on site, once built
        self.calibration_desk = KeeperDesk()  # the API's way to it
        hub = LiveHub(
            p.rig,
            p.site,
            self.report.state,
            EventLog(p.events_db, p.out_dir / "clips"),
            power=self.power.snapshot,
        )
        self.hub = hub
        self.console = Console.in_folder(p.out_dir, hub)
        self.server = self._server()
        self.opcua = self._opcua(opcua)
        self.maintainer = StorageMaintainer(p.out_dir, event_log=p.events_db, settings=p.retention)
        self._watch()
        self.parts = Parts(self._order())
        self._built = True

    def __setattr__(self, name: str, value: object) -> None:
        if getattr(self, "_built", False):
            raise AttributeError(f"the site service is built: {name} cannot be set on it")
        object.__setattr__(self, name, value)

    def _order(self) -> list[Part]:
        """The start order (the close order is its mirror): the HTTP server answers first (its
        health during the start-up), the OPC UA server listens before the cameras open."""
        parts = [
            Part("the HTTP server", self.server.start, self.server.stop),
            Part("the console", self.hub.start, self.console.close),  # its streams end first
        ]
        if self.opcua is not None:  # closed once: a sink of the loop closes it first
            parts.append(Part("the OPC UA server", self.opcua.start, self.opcua.close))
        parts.append(Part("the output folder", self._make_folder, nothing))
        if self.site_desk is not None:  # the first file of the data folder's own
            parts.append(Part("the site desk", self.site_desk.start, nothing))
        parts += [
            Part("the storage maintainer", self.maintainer.start, self._stop_maintainer),
            # the zones' breakers and earthing switches read (a site change: others)
            Part("the zone state's sources", self.power.start, self.power.stop),
        ]
        return parts

    def _server(self) -> Server:
        """The HTTP server (site.http.app) over the console's users and the desks."""
        p = self.plan
        hosts = allowed_hosts(p.http.host, p.config.serve.allowed_hosts)
        desks = Desks(self.desk, self.tickets, self.calibration_desk, self.site_desk, self.warnings)
        app = create_app(self.report.state, console=self.console, allowed_hosts=hosts, desks=desks)
        hint = f"stereopose users add NAME --role admin --config {p.config_path}"
        return Server(app, p.http, users=self.console.users.count, users_hint=hint)

    def _opcua(self, settings: OpcuaSettings | None) -> OpcuaServer | None:
        """[opcua]: the OPC UA server (scada.opcua), an incident output once the frame loop
        runs; its users are the console's. It listens when started (a StereoposeError when it
        cannot)."""
        if settings is None:
            return None
        from stereopose.scada.opcua import CameraNode, OpcuaServer
        from stereopose.scada.opcua_space import site_zones

        p = self.plan
        return OpcuaServer(
            settings,
            site_zones(p.site, p.rig),
            [CameraNode(n) for n in p.rig.names],
            self.console.users,
            incidents=self.desk,  # the book, once the frame loop runs it
            status=lambda: self.report.state.snapshot().status,
            limiter=self.console.limiter,
        )

    def _watch(self) -> None:
        """The standing parts' figures in status.json and the health state."""
        report, packets = self.report, self.packets
        if packets:

            def full_streams() -> dict:
                return {
                    name: {
                        "bytes": r.bytes,
                        "packets": r.packets,
                        "dropped_groups": r.dropped_groups,
                    }
                    for name, r in packets.items()
                }

            report.watch("full_streams", full_streams)
        report.watch("console", self.hub.figures)
        report.state.register_storage(self.maintainer.usage)
        report.watch("storage", self.maintainer.health)
        report.watch("zone_state", self.power.figures)  # None: no zone has a source

    def start(self) -> str:
        """Every standing part started in its order; the HTTP server's address."""
        self.parts.start()
        return self.server.url

    def rig_followers(self) -> list[Callable[[Rig], None]]:
        """What of the service is told a new rig when a camera is placed again: the site's
        views of the zones, the console's."""
        return [x.set_rig for x in (self.site_desk, self.hub) if x is not None]

    def _check_site(self, site: Site) -> None:
        """ConfigError when the running service cannot take `site`: a ticket not yet ended
        names a zone it lacks."""
        if self.tickets is not None:
            self.tickets.check_site(site.zones)

    def close(self) -> None:
        """Every part started, in reverse: the last started first, the HTTP server last. A
        part that fails to close is logged and the others still close."""
        self.parts.close()

    def _make_folder(self) -> None:
        out = self.plan.out_dir
        try:
            make_folder(out)
        except OSError as e:
            raise StereoposeError(f"{out}: cannot create the output folder: {e.strerror}") from None

    def _stop_maintainer(self) -> None:
        if not self.maintainer.stop(5.0):
            logger.warning("storage: the maintainer did not stop within 5 s")


def _tickets(plan: ServePlan, wall_start: float) -> TicketDesk | None:
    """The site's tickets (no zones to name without a site), those planned added (started
    from the console or the API); their times shown as wall times too."""
    if plan.site is None:
        return None
    tickets = TicketDesk(plan.site.zones, wall_start)
    for ticket in plan.tickets:
        tickets.add(ticket)
    return tickets


def _site_desk(plan: ServePlan, check: Callable[[Site], None]) -> SiteDesk | None:
    """The site edited while serving (none where the site has no file)."""
    site = plan.site
    if site is None or site.path is None:
        return None
    return SiteDesk(site.path, site, plan.out_dir / "site-history", check, plan.rig, started=False)
