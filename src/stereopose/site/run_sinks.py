"""The frame loop's sinks under `serve`, opened over the standing service (site.service) once
the cameras are open (their frame rate and clock known): the pose segments, every alarm output
(the event log, the webhook, MQTT, the IEC 104 outstation, the OPC UA server), the clips, the
console's live hub, the health state and `status.json`. Each alarm output is registered in one
place with the incident changes, the health state, /metrics and `status.json`
(`RunSinks.incident_outputs`, site.report)."""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

from stereopose.config import Config
from stereopose.io.sinks import SqliteSink, WebhookSink, close_all
from stereopose.io.sinks.base import Guarded, Sink
from stereopose.io.sinks.health import AlarmOutput
from stereopose.io.summary import RunSummary
from stereopose.pipeline.sources import source_label
from stereopose.site.live import ConsoleSink
from stereopose.site.parts import StateSink, StatusSink
from stereopose.site.service import SiteService

if TYPE_CHECKING:
    from stereopose.alarms import Change
    from stereopose.io.sinks.clips import ClipSink
    from stereopose.io.sinks.mqtt import MqttSink
    from stereopose.scada.iec104 import Outstation

__all__ = ["RunSinks", "open_sinks"]


@dataclass(frozen=True)
class RunSinks:
    """The frame loop's sinks in their closing order, and what of them other parts use: every
    incident output (the console's live channel first), the IEC 104 outstation (shown the
    incidents restored), the MQTT output (the site and the warnings told on it), status.json's
    writer (written again once the outbox has sent the stop's last events)."""

    sinks: list[Sink]
    incident_outputs: tuple[Callable[[Sequence[Change]], None], ...]
    iec104: Outstation | None
    mqtt: MqttSink | None
    status: StatusSink


def open_sinks(
    service: SiteService,
    cfg: Config,
    wall_start: float,
    summary: RunSummary,
    stats: Callable[[], dict],
    arrival: Callable[[float], float | None],
    rates: Callable[[], dict] | None = None,
) -> RunSinks:
    """Every sink, in closing order; if one cannot be opened, those open are closed."""
    p, report, sinks = service.plan, service.report, []
    changes: list[Callable[[Sequence[Change]], None]] = [service.hub.incident_changes]
    made = _Made()

    def guard(sink: Sink, label: object) -> Guarded:
        return Guarded(sink, str(label), report.failed)

    try:
        from stereopose.io.sinks.segments import SegmentSink

        segments = SegmentSink(p.out_dir, cfg.fps, wall_start=wall_start, settings=p.segments)
        sinks.append(guard(segments, p.out_dir / "poses"))
        for out in _alarm_outputs(service, cfg, wall_start, made):  # closed should one fail
            # the output in every place that watches it, under its output_name: the incident
            # changes, the health state, status.json; the loop writes its Guarded wrapper (an
            # output that fails stops alone)
            sink = guard(out, out.label)
            changes.append(out.write_changes)
            report.watch_output(out, sink)
            sinks.append(sink)
        if p.clips is not None and p.site is not None:
            sinks.append(guard(_clips(service, cfg, wall_start), p.out_dir / "clips"))
        sinks.append(ConsoleSink(service.hub, wall_start))
        state = StateSink(
            report.state,
            summary,
            arrival=arrival,
            stats=stats,
            elsewhere=report.elsewhere,
            rates=rates,
        )
        sinks.append(guard(state, "the health state"))
        status = StatusSink(p.status_path, report.snapshot, cfg.serve.status_interval_s)
        sinks.append(guard(status, p.status_path))
    except BaseException:
        close_all(sinks)
        raise
    return RunSinks(sinks, tuple(changes), made.iec104, made.mqtt, status)


@dataclass
class _Made:
    """The alarm outputs that other parts use, once made."""

    mqtt: MqttSink | None = None
    iec104: Outstation | None = None


def _alarm_outputs(
    service: SiteService, cfg: Config, wall_start: float, made: _Made
) -> Iterator[AlarmOutput]:
    """Every alarm output of the configuration (io.sinks.health.AlarmOutput), each made
    when the one before is registered: the event log, the webhook, MQTT, the IEC 104
    outstation, the OPC UA server (started before the cameras opened)."""
    p = service.plan
    site = str(p.site.path or "") if p.site is not None else ""
    yield SqliteSink(
        p.events_db,
        site,
        source_label(list(p.sources)),
        first_id=service.resume.next_id,
        wall_start=wall_start,
    )
    if cfg.outputs.webhook:
        yield WebhookSink(cfg.outputs.webhook)
    if p.mqtt is not None:
        from stereopose.io.sinks.mqtt import MqttSink

        desk = service.site_desk if cfg.mqtt.commands else None  # zones switched over MQTT
        zones = [z.name for z in p.site.zones] if p.site is not None else []
        made.mqtt = MqttSink(p.mqtt, zones, None if desk is None else desk.switch_zone)
        yield made.mqtt
    if cfg.iec104.enabled:
        made.iec104 = _iec104(service, cfg, wall_start)
        yield made.iec104
    if service.opcua is not None:
        yield service.opcua


def _iec104(service: SiteService, cfg: Config, wall_start: float) -> Outstation:
    """The IEC 60870-5-104 outstation (scada.iec104): the zone, camera and service events
    and the incident changes as points, `service degraded` from the health answer."""
    from stereopose.scada.iec104 import Iec104Settings, Outstation
    from stereopose.scada.points import points_table

    p, s, state = service.plan, Iec104Settings.from_config(cfg.iec104), service.report.state
    return Outstation(
        s,
        points_table(p.site, p.rig, commands=s.commands),
        wall_start=wall_start,
        status=lambda: state.snapshot().status,
        acknowledger=service.desk.acknowledge,  # the commands' way to the book, once it runs
    )


def _clips(service: SiteService, cfg: Config, wall_start: float) -> ClipSink:
    from stereopose.io.sinks.clips import ClipSink
    from stereopose.viz.clips import clip_drawer

    p = service.plan
    clips = ClipSink(
        p.out_dir,
        p.rig.names,
        cfg.fps,
        wall_start=wall_start,
        draw=clip_drawer(p.rig),
        settings=p.clips,
        packets=service.packets,
    )
    service.report.state.register_queue("clips", clips.queued, lambda: clips.frames_dropped)
    service.report.watch("clips", clips.figures)
    return clips
