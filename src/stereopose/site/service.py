"""The site service's running parts, built from its plan by serve's composition root
(site.serve) and stopped by it: the HTTP server with the console and its live channel, the
OPC UA server, the storage maintainer, the alarm outputs (each registered in one place with the
incident changes, the health state, /metrics and `status.json`), the event log's outbox, the
watchdog, the incident desk. What the service reports about itself (the health state, each
part's figures, `status.json`) is its `report` (site.report)."""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable, Iterator, Sequence
from typing import TYPE_CHECKING

from stereopose.config import Config
from stereopose.detection.regional import RegionDetector
from stereopose.fence import Site
from stereopose.io.sinks import SqliteSink, WebhookSink, close_all
from stereopose.io.sinks.base import Guarded, Sink
from stereopose.io.sinks.health import AlarmOutput
from stereopose.io.summary import RunSummary
from stereopose.pipeline.sources import source_label
from stereopose.site.desk import IncidentDesk
from stereopose.site.eventlog import EventLog
from stereopose.site.feed import make_outbox
from stereopose.site.health.calib_keeper import KeeperDesk
from stereopose.site.health.state import ServiceState
from stereopose.site.health.watchdog import Watchdog
from stereopose.site.http.api.warnings import WarningsDesk
from stereopose.site.http.app import Desks, create_app
from stereopose.site.http.web import Console
from stereopose.site.live import ConsoleSink, LiveHub
from stereopose.site.parts import (
    StateSink,
    StatusSink,
)
from stereopose.site.plan import ServePlan, packet_rings
from stereopose.site.report import StatusReport
from stereopose.site.restart import Resume
from stereopose.site.site_desk import SiteDesk
from stereopose.site.storage import StorageMaintainer
from stereopose.tickets import TicketDesk
from stereopose.web.hosts import allowed_hosts
from stereopose.web.server import Server
from stereopose.zones.power_state import PowerBoard, ZoneStates

if TYPE_CHECKING:
    from stereopose.alarms import Change, IncidentRecord
    from stereopose.io.sinks.clips import ClipSink
    from stereopose.nodes.fusion import NodeInput
    from stereopose.onsite.service import OnSite
    from stereopose.pipeline.incidents import IncidentStep
    from stereopose.scada.iec104 import Outstation
    from stereopose.scada.opcua_settings import OpcuaSettings
    from stereopose.site.health.calib_keeper import CalibrationKeeper
    from stereopose.types import Rig

__all__ = ["SiteService"]

logger = logging.getLogger(__name__)


class SiteService:
    """The running parts of one `serve`, built from a plan; `run()` once."""

    def __init__(
        self,
        plan: ServePlan,
        stop: threading.Event,
        resume: Resume,
        opcua: OpcuaSettings | None = None,
    ) -> None:
        """opcua: [opcua] checked (scada.opcua_settings; None: off)."""
        self.plan, self.stop, self.resume = plan, stop, resume
        # the parts started, in order (name, its close): closed in reverse (`close`)
        self.parts: list[tuple[str, Callable[[], object]]] = []
        # the health state, the outputs that failed, each part's figures: status.json
        self.report = StatusReport(
            ServiceState(plan.rig.names, camera_timeout_s=plan.config.serve.camera_timeout_s)
        )
        self.incident_outputs: list[Callable] = []  # each given every step's incident changes
        self.iec104 = None  # the IEC 60870-5-104 outstation, when [iec104] is enabled
        self.outbox = None  # the event log as an outbox over MQTT (site.outbox)
        self.console: Console | None = None
        self.maintainer: StorageMaintainer | None = None
        self.status: StatusSink | None = None
        self.packets = packet_rings(plan)
        self.opcua_settings = opcua
        self.opcua = None  # the OPC UA server, once started
        self.watchdog = Watchdog()  # the receivers' threads started again where one died
        self.desk = IncidentDesk()  # the app's way to the incident book, attached once it runs
        # the site's tickets (none without a site: no zones to name)
        self.tickets = TicketDesk(plan.site.zones) if plan.site is not None else None
        for ticket in plan.tickets:  # planned: started from the console or the API
            assert self.tickets is not None  # a ticket comes with its site
            self.tickets.add(ticket)
        # the energized zones' live or dead state from the utility (zones.power_state)
        zones = plan.site.zones if plan.site is not None else ()
        self.power_board = PowerBoard() if any(z.power for z in zones) else None
        self.power = ZoneStates(zones, self.power_board) if self.power_board else None
        self.power_sources = None
        # the site edited while serving (GET/PUT /api/site, SIGHUP): taken at a step's start
        site, history = plan.site, plan.out_dir / "site-history"
        self.site_desk = None
        if site is not None and site.path is not None:
            self.site_desk = SiteDesk(
                site.path, site, history, self._check_site, plan.rig, started=False
            )
        self.warnings = WarningsDesk()  # the API's way to the warnings on site, once built
        self.calibration_desk = KeeperDesk()  # the API's way to it
        if self.packets:
            self.report.probes["full_streams"] = lambda: {
                name: {"bytes": r.bytes, "packets": r.packets, "dropped_groups": r.dropped_groups}
                for name, r in self.packets.items()
            }

    # -- starting -------------------------------------------------------------------------

    def start_server(self) -> str:
        p = self.plan
        log = EventLog(p.events_db, p.out_dir / "clips")
        hub = LiveHub(p.rig, p.site, self.report.state, log, power=self._zone_states)
        self.console = Console.in_folder(p.out_dir, hub)
        self.report.probes["console"] = hub.figures
        self.incident_outputs.append(lambda changes: _live_changes(hub, changes))
        hosts = allowed_hosts(p.http.host, p.config.serve.allowed_hosts)
        app = create_app(
            self.report.state,
            console=self.console,
            allowed_hosts=hosts,
            desks=Desks(
                self.desk, self.tickets, self.calibration_desk, self.site_desk, self.warnings
            ),
        )
        hint = f"stereopose users add NAME --role admin --config {p.config_path}"
        server = Server(app, p.http, users=self.console.users.count, users_hint=hint)
        server.start()
        self._started("the HTTP server", server.stop)
        hub.start()
        self._started("the console", self.console.close)  # its live streams end first
        self.start_opcua()
        return server.url

    def start_maintainer(self) -> None:
        p = self.plan
        self.maintainer = StorageMaintainer(p.out_dir, event_log=p.events_db, settings=p.retention)
        self.report.state.register_storage(self.maintainer.usage)
        self.report.probes["storage"] = self.maintainer.health
        self.maintainer.start()
        self._started("the storage maintainer", self._stop_maintainer)

    def start_opcua(self) -> None:
        """[opcua]: the OPC UA server (scada.opcua) listening, an incident output from now
        on; its users are the console's. A StereoposeError when it cannot listen."""
        settings, p = self.opcua_settings, self.plan
        if settings is None or self.console is None:
            return
        from stereopose.scada.opcua import CameraNode, OpcuaServer
        from stereopose.scada.opcua_space import site_zones

        server = OpcuaServer(
            settings,
            site_zones(p.site, p.rig),
            [CameraNode(n) for n in p.rig.names],
            self.console.users,
            incidents=self.desk,  # the book, once the frame loop runs it
            status=lambda: self.report.state.snapshot().status,
            limiter=self.console.limiter,
        )
        server.start()
        self.opcua = server  # an alarm output once the frame loop opens its sinks
        self._started("the OPC UA server", server.close)  # once: a sink of the loop closes it

    def open_sinks(
        self,
        cfg: Config,
        wall_start: float,
        summary: RunSummary,
        stats: Callable[[], dict],
        arrival: Callable[[float], float | None],
        rates: Callable[[], dict] | None = None,
    ) -> list[Sink]:
        """Every sink, in closing order; if one cannot be opened, those open are closed."""
        p, sinks = self.plan, []
        if self.tickets is not None:
            self.tickets.wall_start = wall_start  # the tickets' times shown as wall times too

        def guard(sink: Sink, label: object) -> Guarded:
            return Guarded(sink, str(label), self.report.failed)

        try:
            from stereopose.io.sinks.segments import SegmentSink

            sinks.append(
                guard(
                    SegmentSink(p.out_dir, cfg.fps, wall_start=wall_start, settings=p.segments),
                    p.out_dir / "poses",
                )
            )
            for out in self._alarm_outputs(cfg, wall_start):  # each closed should a later fail
                sinks.append(self._register(out, guard))
            if p.mqtt is not None and cfg.mqtt.outbox:
                self._start_outbox(cfg)
            if p.clips is not None and p.site is not None:
                sinks.append(guard(self._clips(cfg, wall_start), p.out_dir / "clips"))
            if self.console is not None and self.console.hub is not None:
                sinks.append(ConsoleSink(self.console.hub, wall_start))
            state = StateSink(
                self.report.state,
                summary,
                arrival=arrival,
                stats=stats,
                elsewhere=self.report.elsewhere,
                rates=rates,
            )
            sinks.append(guard(state, "the health state"))
            status_s = cfg.serve.status_interval_s
            self.status = StatusSink(p.status_path, self.report.snapshot, status_s)
            sinks.append(guard(self.status, p.status_path))
        except BaseException:
            close_all(sinks)
            raise
        return sinks

    def _alarm_outputs(self, cfg: Config, wall_start: float) -> Iterator[AlarmOutput]:
        """Every alarm output of the configuration (io.sinks.health.AlarmOutput), each made
        when the one before is registered: the event log, the webhook, MQTT, the IEC 104
        outstation, the OPC UA server (started before the cameras opened)."""
        p = self.plan
        site = str(p.site.path or "") if p.site is not None else ""
        yield SqliteSink(
            p.events_db,
            site,
            source_label(list(p.sources)),
            first_id=self.resume.next_id,
            wall_start=wall_start,
        )
        if cfg.outputs.webhook:
            yield WebhookSink(cfg.outputs.webhook)
        if p.mqtt is not None:
            from stereopose.io.sinks.mqtt import MqttSink

            desk = self.site_desk if cfg.mqtt.commands else None  # zones switched over MQTT
            zones = [z.name for z in p.site.zones] if p.site is not None else []
            yield MqttSink(p.mqtt, zones, None if desk is None else desk.switch_zone)
        if cfg.iec104.enabled:
            yield self._iec104(cfg, wall_start)
        if self.opcua is not None:
            yield self.opcua

    def _register(self, out: AlarmOutput, guard: Callable[[Sink, object], Guarded]) -> Guarded:
        """One alarm output in every place that watches it, under its output_name: the
        incident changes, the health state's queues and outputs (so /api/health and /metrics),
        `status.json`'s figures. The sink the frame loop writes is its Guarded wrapper (an
        output that fails stops alone)."""
        sink = guard(out, out.label)
        self.incident_outputs.append(out.write_changes)
        self.report.watch_output(out, sink)
        return sink

    def _start_outbox(self, cfg: Config) -> None:
        """The event log sent over MQTT to a control room (site.feed, site.outbox), watched by
        the watchdog."""
        self.outbox = make_outbox(self.plan, cfg, self.report.state, self.desk.acknowledge)
        self.report.probes["outbox"] = self.outbox.figures
        self.report.state.register_output("outbox", self.outbox.health)
        self._started("the outbox", self._close_outbox)
        self._watch("outbox", self.outbox.ensure_running)

    def _iec104(self, cfg: Config, wall_start: float) -> Outstation:
        """The IEC 60870-5-104 outstation (scada.iec104): the zone, camera and service events
        and the incident changes as points, `service degraded` from the health answer."""
        from stereopose.scada.iec104 import Iec104Settings, Outstation
        from stereopose.scada.points import points_table

        p, s = self.plan, Iec104Settings.from_config(cfg.iec104)
        station = Outstation(
            s,
            points_table(p.site, p.rig, commands=s.commands),
            wall_start=wall_start,
            status=lambda: self.report.state.snapshot().status,
            acknowledger=self.desk.acknowledge,  # the commands' way to the book, once it runs
        )
        self.iec104 = station
        return station

    def _clips(self, cfg: Config, wall_start: float) -> ClipSink:
        from stereopose.io.sinks.clips import ClipSink
        from stereopose.viz.clips import clip_drawer

        p = self.plan
        clips = ClipSink(
            p.out_dir,
            p.rig.names,
            cfg.fps,
            wall_start=wall_start,
            draw=clip_drawer(p.rig),
            settings=p.clips,
            packets=self.packets,
        )
        self.report.state.register_queue("clips", clips.queued, lambda: clips.frames_dropped)
        self.report.probes["clips"] = clips.figures
        return clips

    def rig_followers(self) -> list[Callable[[Rig], None]]:
        """What of the service is told a new rig when a camera is placed again: the site's
        views of the zones, the console's."""
        hub = self.console.hub if self.console is not None else None
        return [x.set_rig for x in (self.site_desk, hub) if x is not None]

    def keep_calibration(self, keeper: CalibrationKeeper) -> None:
        """The calibration keeper's figures in status.json; closed with the service."""
        self.calibration_desk.keeper = keeper
        self.report.probes["calibration"] = keeper.figures
        self._started("the calibration keeper", keeper.close)

    def attach_incidents(self, step: IncidentStep, restored: list[IncidentRecord]) -> None:
        """The frame loop's incident step, once it runs: its figures in status.json and
        /metrics; the acts of the HTTP API, the IEC 104 outstation's commands and a control
        room's acknowledgements reach its book through the desk (given to each when made);
        the outstation and the OPC UA server show the incidents restored."""
        self.report.probes["alarms"] = step.figures
        self.report.state.register_alarms(step.figures)  # in /metrics
        self.desk.attach(step)
        if self.iec104 is not None:  # its commands reach the book through the desk
            self.iec104.incidents(restored)
        if self.opcua is not None:  # its Acknowledge through the desk; the restored shown
            self.opcua.show_book()

    def warn_on_site(self, onsite: OnSite) -> None:
        """The warnings on site to the API (what sounds, an admin's silences and tests),
        closed with the service: every speaker quiet, every coil off."""
        self.warnings.onsite = onsite
        self.report.probes["warnings_on_site"] = onsite.figures

        def close() -> None:
            self.warnings.onsite = None
            onsite.close()

        self._started("the warnings on site", close)

    def watch_nodes(self, nodes: NodeInput) -> None:
        """The detection nodes' input: its queue, figures and the cameras' light reported
        (site.report), its MQTT receiver's thread watched (started again should it die)."""
        self.report.watch_nodes(nodes)
        self._watch("nodes", nodes.ensure_running)

    def watch_regions(self, regions: RegionDetector) -> None:
        """Detection in regions' figures by camera in status, /metrics and the console."""
        self.report.watch_regions(regions)
        if self.console is not None and self.console.hub is not None:
            self.console.hub.show_regions(regions.view)

    def start_power(self) -> None:
        """The zones' state sources (IEC 104 masters, OPC UA clients, the MQTT subscriber),
        each on its own thread; the console's zones and the status show their states. One
        part, closed with the service, stops whichever sources run then (a site change
        replaces them: restart_power)."""
        self._started("the zone state's sources", self._stop_sources)
        if self.power is not None and self.plan.site is not None:
            self._start_sources(self.plan.site)

    def _start_sources(self, site: Site) -> None:
        from stereopose.site.zone_sources import start_sources

        p, board, states = self.plan, self.power_board, self.power
        assert board is not None and states is not None  # the site's zones have sources
        sources = start_sources(site.zones, board, mqtt=p.mqtt, base=p.config_path.resolve().parent)
        self.power_sources = sources
        self.report.probes["zone_state"] = lambda: {
            "zones": states.snapshot(),
            "sources": dict(sources.figures),
        }

    def _zone_states(self) -> dict:
        """The energized zones' states now, from the sources that run (empty: none)."""
        return self.power.snapshot() if self.power is not None else {}

    def _check_site(self, site: Site) -> None:
        """ConfigError when the running service cannot take `site`: a ticket not yet ended
        names a zone it lacks."""
        if self.tickets is not None:
            self.tickets.check_site(site.zones)

    def restart_power(self, site: Site) -> ZoneStates | None:
        """The zones' state sources made `site`'s (the frame loop's thread, at a site change):
        the old ones stopped, new ones started; the new ZoneStates (None: none has a source)."""
        self._stop_sources()
        self.power_board = PowerBoard() if any(z.power for z in site.zones) else None
        self.power = ZoneStates(site.zones, self.power_board) if self.power_board else None
        self.report.probes.pop("zone_state", None)
        if self.power is not None:
            self._start_sources(site)
        return self.power

    # -- stopping ---------------------------------------------------------------------------

    def close(self) -> None:
        """Every part started, in reverse: the last started first, the HTTP server last;
        status.json written again once the outbox has sent the stop's last events. A part
        that fails to close is logged and the others still close."""
        while self.parts:
            name, close = self.parts.pop()
            try:
                close()
            except Exception as e:  # one part never keeps the others open
                logger.warning("closing %s: %s", name, e)

    def _started(self, name: str, close: Callable[[], object]) -> None:
        self.parts.append((name, close))

    def _watch(self, name: str, ensure_running: Callable[[], None]) -> None:
        """A receiver's thread watched (started again should it die); the watchdog started
        with the first, stopped before the parts it watches."""
        self.watchdog.add(name, ensure_running)
        if not any(n == "the watchdog" for n, _ in self.parts):
            self.watchdog.start()
            self._started("the watchdog", self.watchdog.stop)

    def _stop_sources(self) -> None:
        """The zones' state sources that run now stopped (none: nothing to do)."""
        sources, self.power_sources = self.power_sources, None
        if sources is not None:
            sources.stop()

    def _stop_maintainer(self) -> None:
        if self.maintainer is not None and not self.maintainer.stop(5.0):
            logger.warning("storage: the maintainer did not stop within 5 s")

    def _close_outbox(self) -> None:
        if self.outbox is not None:
            self.outbox.close()  # sends what the log holds: status.json counts it
        if self.status is not None:
            self.status.write_now()


def _live_changes(hub: LiveHub, changes: Sequence[Change]) -> None:
    """Each incident change to the console's live channel, as an `incident` message."""
    for c in changes:
        hub.publish("incident", c.to_dict())
