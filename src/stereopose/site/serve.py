"""`stereopose serve`: the frame loop for ever, with bounded storage, alarms out and health.

Once the configuration is checked (site.plan: exit 2 before any work), the service
starts its HTTP server (site.http.app: /api/health, /metrics, the operator console over the
users of `<output>/users.json`), opens the cameras and runs the
frame loop over them until SIGTERM or SIGINT. Under systemd it says it is ready at the
first step and feeds the watchdog while steps advance (site.watchdog). Its sinks, in their
closing order:

- pose segments `poses/<UTC start>.jsonl.gz` (io.sinks.segments);
- the event log `events.sqlite` (appended to across restarts), the webhook when
  [outputs] webhook is set, MQTT when [mqtt] host is set, the IEC 60870-5-104 outstation
  when [iec104] is enabled (scada.iec104; also an incident output);
- event clips `clips/` (io.sinks.clips) unless [storage] clips = false;
- the console's live hub (site.live: people, zones, camera pictures for the page);
- the health state (site.health.state) and `status.json`, its snapshot every status_interval_s;
  every alarm output (the event log, the webhook, MQTT; any later one with a `health()`, see
  io.sinks.health) is registered with it, so health is degraded while one fails.

The data folder is private: the service runs with a umask of 077 and takes group and other
permissions off what an earlier run left (pipeline.private). Its HTTP server answers only
the Host names of web.hosts.allowed_hosts ([serve] allowed_hosts adds some).

With [opcua] enabled, the OPC UA server (scada.opcua: the site's zones, cameras and counts,
each incident an alarm condition, logins as the console's users) listens from the start,
before the cameras open; it is an incident output and a sink, closed with the event sinks.

Recorded files are played as live cameras: every step, and so every event, is stamped with
when its frames were read, seconds since the service's t = 0 (wall time = wall_start + t). A
stall of the whole service (the machine overloaded or the process paused: every camera late at
once) is one service_stalled / service_resumed pair, not a camera_down per camera, and ends no
track (site.steps). Health is degraded while a camera is processed far under its
nominal rate or drops most of its frames (site.health.state).

One storage maintainer thread (site.storage) applies [storage]'s retention and cap. Events
other than zone events (a camera down or up, the service stalled or resumed, calibration drift,
a zone closed at restart) go through the same event sinks. A stop closes every output, each
within its own bound, then the maintainer and the server; a second signal meanwhile is ignored.

Nothing is kept per frame: the summary holds running aggregates, every queue is bounded.
"""

from __future__ import annotations

import dataclasses
import logging
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from stereopose.alarms import IncidentBook
from stereopose.config import Config
from stereopose.detection import choice_of, make_detector
from stereopose.detection.base import PoseDetector
from stereopose.extras import require
from stereopose.fence import Site
from stereopose.io.cameraset import CameraSet
from stereopose.io.sinks import close_all
from stereopose.io.sinks.base import ClosesOnce, FrameResult, Sink
from stereopose.io.sinks.incidents import IncidentIds
from stereopose.io.summary import RunSummary
from stereopose.nodes.fusion import NodeInput
from stereopose.onsite.service import OnSite
from stereopose.pipeline.incidents import IncidentStep
from stereopose.pipeline.loop import FrameLoop
from stereopose.pipeline.private import private_files, tighten
from stereopose.pipeline.stage3d import Stage3D
from stereopose.scada.opcua_settings import opcua_settings
from stereopose.site.cameras import open_cameras, people_source
from stereopose.site.health.calib_health import CalibrationHealth
from stereopose.site.health.calib_keeper import CalibrationKeeper, KeeperSettings
from stereopose.site.health.watch import CameraWatch
from stereopose.site.parts import (
    ServeSource,
    quiet_signals,
    reload_signal,
    stop_signals,
)
from stereopose.site.plan import (
    ServePlan,
    disabled_settings,
    interfaces,
    plan_serve,
)
from stereopose.site.restart import Resume
from stereopose.site.run_parts import RunParts
from stereopose.site.run_sinks import RunSinks, open_sinks
from stereopose.site.service import SiteService
from stereopose.site.site_parts import mqtt_site
from stereopose.site.site_switch import Outliving, SiteSwitch
from stereopose.site.steps import HeldStage, ServeEvents, StepHooks
from stereopose.site.watchdog import Notifier, Watchdog
from stereopose.types import Rig

__all__ = ["ServeResult", "plan_serve", "serve"]

logger = logging.getLogger(__name__)

HEARTBEAT_S = 0.5  # the longest the loop goes without a step while no camera delivers


@dataclass
class ServeResult:
    """What a service run did: its summary, the address it served on, the outputs closed and
    those that failed on the way (each output that failed stops alone, the service goes on)."""

    summary: RunSummary
    url: str
    outputs: list[Path] = field(default_factory=list)
    failed: dict[str, str] = field(default_factory=dict)


class _Closing(ClosesOnce):
    """The first sink closed: from then on a signal no longer cuts the closing short."""

    stage = "write"

    def __init__(self) -> None:
        self._quiet = quiet_signals()

    def write(self, frame: FrameResult) -> None:
        pass

    def _close(self) -> list[Path]:
        self._quiet.__enter__()  # left by serve once everything is closed
        return []

    def release(self) -> None:
        if self._closed:
            self._quiet.__exit__(None, None, None)


def serve(
    config_path: str | Path,
    *,
    plan: ServePlan | None = None,
    stop: threading.Event | None = None,
    on_ready: Callable[[str], None] | None = None,
) -> ServeResult:
    """Serve the configuration at `config_path` until `stop` is set, SIGINT or SIGTERM.

    plan: already checked (plan_serve); on_ready(url): once the HTTP server answers. Returns
    when every output is closed. A ConfigError (bad configuration) or a ServeError (the port
    taken) comes before any output is written.
    """
    plan = plan or plan_serve(config_path)
    with private_files():  # before any file of the service is made
        tighten(plan.out_dir)
        return _serve(plan, stop or threading.Event(), on_ready)


def _serve(
    plan: ServePlan, stop: threading.Event, on_ready: Callable[[str], None] | None
) -> ServeResult:
    cfg = plan.config
    if cfg.iec104.enabled:  # before any work: the extra named, not an ImportError later
        require("c104", "scada", "the IEC 60870-5-104 outstation ([iec104] enabled)")
    shown = ", ".join(interfaces(cfg, plan.site))
    logger.info("interfaces: %s", shown)  # the command prints it too
    for warning in disabled_settings(cfg):
        logger.warning("%s: %s", plan.config_path, warning)
    d = cfg.detector  # none in this process when the nodes detect
    detector = (
        None
        if cfg.input.detection == "nodes"
        else make_detector(
            d.backend, plan.model, d.imgsz, d.conf, d.iou, d.device, d.threads, d.precision
        )
    )
    resume = Resume.from_log(plan.events_db)  # before any id is given or event written
    if resume.occupied:
        logger.warning(
            "restart: %d zone occupancy(ies) left open by the last run are closed",
            len(resume.occupied),
        )
    if resume.alarms:
        logger.warning(
            "restart: %d behaviour alarm(s) left open by the last run are ended", len(resume.alarms)
        )
    # [opcua] checked before any work: a ConfigError naming the file and the key
    service = SiteService(plan, resume, opcua=opcua_settings(plan.config_path, cfg, plan.out_dir))
    service.report.watch_detector(choice_of(detector))  # status.json: what detects, and why
    closing = _Closing()
    # systemd told the service is ready at the first step, and fed while steps advance
    watchdog = Watchdog(Notifier(), status=lambda: service.report.state.snapshot().status)
    reload = service.site_desk.reload if service.site_desk is not None else None
    with stop_signals(), reload_signal(reload):
        try:
            url = service.start()  # every standing part, in its order
            if on_ready is not None:
                on_ready(url)
            opened_t = service.clock.since(time.monotonic())  # a camera silent since: down
            with open_cameras(plan, service.packets, service.clock) as cams:
                summary = _run_loop(
                    plan, service, cams, detector, stop, [closing, watchdog], opened_t
                )
        finally:
            with quiet_signals():
                service.close()
            closing.release()
    return ServeResult(summary, url, summary.outputs, dict(service.report.failed))


def _calib_health(plan: ServePlan, cfg: Config) -> CalibrationHealth:
    """The calibration's health: each camera's drift from the people's reprojection."""
    s = cfg.serve
    return CalibrationHealth(
        plan.rig,
        s.calib_warn_factor,
        baseline_samples=s.calib_baseline_samples,
        window=s.calib_window_samples,
    )


def _keeper(
    plan: ServePlan,
    cfg: Config,
    calib: CalibrationHealth,
    follow: Sequence[Callable[[Rig], None]],
) -> CalibrationKeeper:
    """The calibration keeper (a drifted camera placed again), telling `follow` each new rig."""
    s = cfg.serve
    return CalibrationKeeper(
        plan.rig,
        plan.calib_path,
        calib,
        apply=follow,
        settings=KeeperSettings(s.calibration_auto, s.calibration_samples),
        out_dir=plan.out_dir,
        loaded=plan.calib_loaded,
    )


def _run_loop(
    plan: ServePlan,
    service: SiteService,
    cams: CameraSet | NodeInput,
    detector: PoseDetector | None,
    stop: threading.Event,
    first: list[Sink],
    opened_t: float,
) -> RunSummary:
    """The frame loop over the open cameras: its stages and sinks, and the run's own parts
    (site.run_parts), closed when it ends. opened_t: when the cameras were opened, on the
    service's clock (a camera that never delivers is down timeout_s after)."""
    cfg = dataclasses.replace(plan.config, fps=cams.fps)
    rig = plan.rig
    timeout_s = cfg.serve.camera_timeout_s
    watch = CameraWatch(rig.names, timeout_s, start=opened_t)
    calib = _calib_health(plan, cfg)
    follow = service.rig_followers()  # a camera placed again: each told the new rig

    def now_t() -> float:  # the service's clock: the steps' and the events' t
        return cams.clock.since(time.monotonic())

    people = people_source(plan, service, cams, detector, cfg)
    follow += people.rig_followers
    on_site = list(people.site_followers)  # each told every new site
    # each person id reserved in the log before it is given (site.person_ids)
    stage = Stage3D(
        rig,
        cfg,
        calib_path=str(plan.calib_loaded or plan.calib_path),
        first_id=service.resume.person_ids(plan.events_db),
    )
    follow.append(stage.set_rig)  # from the next step
    keeper = _keeper(plan, cfg, calib, follow)
    hooks = StepHooks(
        service.resume.closing_events,
        fresh=lambda name: cams.delivering(name, timeout_s),
        clock=now_t,
        on_stall=service.report.state.service_stall,
        lost=cams.lost if isinstance(cams, CameraSet) else None,
    )
    events = ServeEvents(watch, calib, hooks, keeper=keeper)
    # an empty step's time: now, or for the nodes now less their frames' longest way here (a
    # step's time is its capture time, and the steps' times only rise)
    lag_s = cams.lag_s if isinstance(cams, NodeInput) else 0.0
    source = ServeSource(
        people.steps,
        stop=stop,
        heartbeat_s=HEARTBEAT_S,
        on_step=events.step,
        on_detect=events.detected,
        clock=lambda: now_t() - lag_s,
    )
    # a step the service was too late for is no observation; a stall's length not their age
    stage = HeldStage(stage, events.time)
    summary = RunSummary(
        rig.names,
        source.stages,
        cfg.reconstruction.triangulation.mode,
        stage.tracking,
        live=source.live,
        fps_input=source.fps,
        out_dir=plan.out_dir,
        config_path=plan.config_path,
    )
    start_mono = cams.clock.start

    def arrival(t: float) -> float | None:
        return start_mono + t if source.live or cams.wall_clock else None

    sinks = open_sinks(
        service, cfg, cams.clock.start_epoch, summary, cams.stats, arrival, people.rates
    )
    try:
        run = RunParts(service, cfg, sinks, keeper, cams if isinstance(cams, NodeInput) else None)
    except BaseException:  # e.g. the outbox's broker cannot be resolved: the sinks closed
        close_all(sinks.sinks)
        keeper.close()
        raise
    on_site += mqtt_site(sinks.mqtt, plan.site)
    if run.onsite is not None:
        on_site.append(run.onsite.set_site)
    logger.info("serving %s: outputs in %s", ", ".join(cams.names), plan.out_dir)
    ids = IncidentIds(plan.events_db)
    try:
        run.parts.start()
        switch = _site_switch(service, events, cfg, on_site, run.onsite)
        incidents = _incidents(plan, service, switch, ids, sinks, now_t)
        loop = FrameLoop(source, stage, [*first, *sinks.sinks], summary, rules=incidents, stop=stop)
        return loop.run()
    finally:
        ids.close()
        run.parts.close()


def _incidents(
    plan: ServePlan,
    service: SiteService,
    switch: SiteSwitch,
    ids: IncidentIds,
    sinks: RunSinks,
    clock: Callable[[], float],
) -> IncidentStep:
    """The incident book over the step's events (pipeline.incidents), on the rules of the
    plan's site (`switch.rules`; a new site taken at a step's start by `switch` where the
    site can change): ids from the log's mark, the incidents the last run left open restored
    (on this run's clock: its Unix start and its time now), its changes stored with the step's
    events and given to every incident output. Attached to the service's incident desk: the
    acts of the HTTP API, the IEC 104 outstation's commands and a control room's
    acknowledgements reach its book through it; the outstation and the OPC UA server show the
    incidents restored."""
    wall_start = service.clock.start_epoch
    rules = switch.rules(plan.site)
    book = IncidentBook(rules.settings, next_id=ids)
    restored = book.restore(service.resume.open_incidents(wall_start))
    if restored:
        logger.warning("restart: %d incident(s) left open by the last run are open again", restored)
    # the event log is an incident output (its records stored in the step's transaction)
    step = IncidentStep(
        book,
        rules.chain,
        holding=rules.holding,
        outputs=list(sinks.incident_outputs),
        clock=clock,
        wall_start=wall_start,
        switch=switch if switch.desk is not None else None,
    )
    service.report.watch("alarms", step.figures)
    service.report.state.register_alarms(step.figures)  # in /metrics
    service.desk.attach(step)
    if sinks.iec104 is not None:
        sinks.iec104.incidents(book.incidents())
    if service.opcua is not None:
        service.opcua.show_book()
    return step


def _site_switch(
    service: SiteService,
    events: ServeEvents,
    cfg: Config,
    on_site: list[Callable[[Site], None]],
    onsite: OnSite | None,
) -> SiteSwitch:
    """What builds the step's rules on a site and takes a new one from the service's site desk
    (the API, SIGHUP; none: the site never changes) at a step's start (site.site_switch), on
    the run's settings; on_site: told each new site (the regions' scans, the MQTT output's
    `site`). The tickets, the zones' states and the warnings on site (`onsite`) outlive a
    site."""
    return SiteSwitch(
        service.site_desk,
        events,
        cfg,
        kept=Outliving(service.tickets, service.power.states, onsite),
        restart_power=service.power.restart,
        scene=service.hub.scene,
        on_site=on_site,
    )
