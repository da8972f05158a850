"""What `stereopose serve` reads from its configuration, checked before any work.

`plan_serve(config_path)` loads the configuration and checks everything the service needs: the
calibration and its cameras, the site, the model, every setting of [serve], [mqtt] and
[storage] (each building block's own settings, so a bad value is a ConfigError naming the file
and `section.key`), and that no output of the service's folder is one of its inputs. Nothing is
written and nothing opened but the files read.
"""

from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass
from pathlib import Path
from urllib.parse import urlsplit

from stereopose.config import Config, load_config
from stereopose.config.scada import Iec104Config, OpcuaConfig
from stereopose.config_refs import (
    mqtt_settings,
    resolve,
    section_settings,
    source_path,
    tls_files,
)
from stereopose.errors import CalibrationError, ConfigError
from stereopose.fence import Site, load_site
from stereopose.io.datafolder import CLIPS_DIR, EVENTS_DB, POSES_DIR, STATUS
from stereopose.io.packets import PacketRing
from stereopose.io.sinks.clips import ClipSettings
from stereopose.io.sinks.mqtt_settings import MqttSettings
from stereopose.io.sinks.segments import SegmentSettings
from stereopose.io.video import is_stream
from stereopose.pipeline.outputs import Outputs, check_outputs
from stereopose.pipeline.paths import Place, check_places, places, sqlite_places
from stereopose.pipeline.run import check_run_config, run_rig
from stereopose.secrets import redact
from stereopose.site.health.calib_keeper import corrected_file
from stereopose.site.storage import RetentionSettings
from stereopose.tickets.ticket import Ticket, check_ticket_site, load_ticket
from stereopose.types import Rig
from stereopose.web.server import ServeSettings

logger = logging.getLogger(__name__)

_GB = 10**9


@dataclass(frozen=True)
class ServePlan:
    """The service's configuration, checked: paths resolved against the config file's folder
    (sources: one per camera, URLs as written; detect_sources: the detection substreams, ""
    where the main source is used), and the building blocks' settings (mqtt: None when off)."""

    config_path: Path
    config: Config
    rig: Rig
    calib_path: Path
    site: Site | None
    site_path: Path | None
    sources: tuple[str, ...]
    detect_sources: tuple[str, ...]
    model: Path | None
    out_dir: Path
    http: ServeSettings
    mqtt: MqttSettings | None
    segments: SegmentSettings
    clips: ClipSettings | None
    retention: RetentionSettings
    tickets: tuple[Ticket, ...] = ()
    # the calibration loaded: calib_path, or the keeper's correction of it (calibration_corrected)
    calib_loaded: Path | None = None

    @property
    def events_db(self) -> Path:
        return self.out_dir / EVENTS_DB

    @property
    def status_path(self) -> Path:
        return self.out_dir / STATUS


def _storage(
    path: Path, cfg: Config
) -> tuple[SegmentSettings, ClipSettings | None, RetentionSettings]:
    s = cfg.storage
    segments = section_settings(path, SegmentSettings, segment_s=s.segment_s)
    clips = (
        section_settings(path, ClipSettings, clip_pre_s=s.clip_pre_s, clip_post_s=s.clip_post_s)
        if s.clips
        else None
    )
    retention = section_settings(
        path,
        RetentionSettings,
        retention_days=s.retention_days,
        clip_retention_days=s.clip_retention_days,
        event_retention_days=s.event_retention_days,
        max_bytes=round(s.max_gb * _GB),
        interval_s=s.maintenance_interval_s,
    )
    return segments, clips, retention


def _check_cameras(path: Path, cfg: Config) -> None:
    """What the service adds to a run's cameras: loop only for a recorded file; a webhook URL
    it can post to."""
    for i, c in enumerate(cfg.cameras):
        if c.loop and is_stream(c.source):
            raise ConfigError(
                f"{path}: cameras[{i}].loop: only a recorded file can be looped, "
                f"got the stream {redact(c.source)!r}"
            )
    hook = cfg.outputs.webhook
    if hook is not None:
        parts = urlsplit(hook)
        try:
            ok = parts.scheme in ("http", "https") and bool(parts.hostname)
            parts.port  # noqa: B018  # a port that is not a number raises
        except ValueError:
            ok = False
        if not ok:
            raise ConfigError(
                f"{path}: outputs.webhook: expected an http:// or https:// URL, got {hook!r}"
            )


def _check_places(plan: ServePlan) -> None:
    """No output of the service's folder may be an input or lie in an input folder."""
    inputs = places(
        ("configuration", plan.config_path),
        ("calibration", plan.calib_path),
        ("site", plan.site_path),
        ("detector.model", plan.model),
    )
    for key, values in (("source", plan.sources), ("detect", plan.detect_sources)):
        inputs += [
            Place(f"cameras[{i}].{key}", Path(s))
            for i, s in enumerate(values)
            if s and not is_stream(s)
        ]
    out = plan.out_dir
    outputs = [
        Place(f"{POSES_DIR}/ in the output folder", out / POSES_DIR, folder=True),
        Place(f"{CLIPS_DIR}/ in the output folder", out / CLIPS_DIR, folder=True),
        Place(f"{STATUS} in the output folder", plan.status_path),
    ]
    outputs += sqlite_places(f"{EVENTS_DB} in the output folder", plan.events_db)
    hint = f'set `output` in {plan.config_path} to a folder of its own (such as "out/serve")'
    check_places(inputs, outputs, hint)


def plan_serve(config_path: str | Path, config: Config | None = None) -> ServePlan:
    """The checked plan of the configuration at `config_path` (config: already loaded from it,
    as the demo does); a ConfigError (exit 2) naming the file and the key otherwise."""
    path = Path(config_path)
    cfg = config if config is not None else load_config(path)
    check_run_config(cfg, path)
    _check_cameras(path, cfg)
    base = path.resolve().parent
    calib_path = resolve(base, cfg.calibration or "")
    rig, calib_loaded = _rig(path, calib_path, resolve(base, cfg.output), cfg)
    site_path = resolve(base, cfg.site) if cfg.site else None
    site = load_site(site_path) if site_path is not None else None
    check_outputs(cfg, site, Outputs())  # the service's: nothing smoothed both ways
    certificate, key = tls_files(path, base, cfg)
    http = section_settings(
        path,
        ServeSettings,
        host=cfg.serve.host,
        port=cfg.serve.port,
        certificate=certificate,
        key=key,
        trusted_proxies=cfg.serve.trusted_proxies,
    )
    segments, clips, retention = _storage(path, cfg)
    mqtt_points = [
        z.name
        for z in (site.zones if site is not None else ())
        if z.power is not None and any(pt.protocol == "mqtt" for pt in z.power.points)
    ]
    if mqtt_points and not cfg.mqtt.host:
        raise ConfigError(
            f"{path}: zone {mqtt_points[0]!r} of {site_path} takes its state over MQTT: set "
            "[mqtt] host (the site's broker)"
        )
    if cfg.input.detection == "nodes" and not cfg.mqtt.host:
        raise ConfigError(
            f'{path}: input.detection = "nodes": the nodes\' people come over '
            "the site's broker; set [mqtt] host"
        )
    plan = ServePlan(
        config_path=path,
        config=cfg,
        rig=rig,
        calib_path=calib_path,
        site=site,
        site_path=site_path,
        sources=tuple(source_path(base, c.source) for c in cfg.cameras),
        detect_sources=tuple(source_path(base, c.detect) for c in cfg.cameras),
        model=resolve(base, cfg.detector.model) if cfg.detector.model else None,
        out_dir=resolve(base, cfg.output),
        http=http,
        mqtt=mqtt_settings(path, base, cfg),
        segments=segments,
        clips=clips,
        retention=retention,
        tickets=_tickets(path, base, cfg, site),
        calib_loaded=calib_loaded,
    )
    _check_places(plan)
    return plan


def _rig(path: Path, calib_path: Path, out_dir: Path, cfg: Config) -> tuple[Rig, Path]:
    """The rig the service starts with, and its file: the one the configuration names, or the
    correction the calibration keeper wrote of it (newer than it; `calibration_corrected`). A
    correction that cannot be used is logged and the original loaded."""
    fixed = corrected_file(calib_path, [out_dir]) if cfg.serve.calibration_corrected else None
    if fixed is not None:
        try:
            rig = run_rig(path, fixed, cfg)
        except (CalibrationError, ConfigError) as e:
            logger.error("%s: the corrected calibration is not used: %s", fixed, e)
        else:
            logger.warning("calibration: %s (the service's correction of %s)", fixed, calib_path)
            return rig, fixed
    return run_rig(path, calib_path, cfg), calib_path


def _tickets(path: Path, base: Path, cfg: Config, site: Site | None) -> tuple[Ticket, ...]:
    """`[serve] tickets`: each file loaded and checked against the site; ids unique."""
    out: list[Ticket] = []
    for i, name in enumerate(cfg.serve.tickets):
        if site is None:
            raise ConfigError(f"{path}: serve.tickets[{i}]: tickets need a site file (`site`)")
        ticket = load_ticket(resolve(base, name))
        check_ticket_site(ticket, site)
        if any(t.id == ticket.id for t in out):
            raise ConfigError(
                f"{path}: serve.tickets[{i}]: {ticket.path}: ticket id {ticket.id!r} is taken"
            )
        out.append(ticket)
    return tuple(out)


def interfaces(cfg: Config, site: Site | None = None) -> list[str]:
    """Which optional interface of the service is on, and where, for its first log line;
    with the site, its warnings on site (speakers and signals)."""
    shown = []
    m = cfg.mqtt
    shown.append(f"MQTT on {m.host}:{m.port} (site {m.site})" if m.host else "MQTT off")
    shown.append("webhook on" if cfg.outputs.webhook else "webhook off")
    i = cfg.iec104
    shown.append(f"IEC 104 on {i.host}:{i.port}" if i.enabled else "IEC 104 off")
    o = cfg.opcua
    shown.append(f"OPC UA on opc.tcp://{o.host}:{o.port}{o.path}" if o.enabled else "OPC UA off")
    w = site.warnings if site is not None else None
    shown.append(
        f"warnings on site: {len(w.speakers)} speaker(s), {len(w.signals)} signal(s)"
        if w is not None
        else "warnings on site off"
    )
    return shown


def disabled_settings(cfg: Config) -> list[str]:
    """A warning for each interface left off whose section sets keys all the same: the
    operator meant it on, most likely."""
    out = []
    sections: tuple[tuple[str, str, Iec104Config | OpcuaConfig], ...] = (
        ("iec104", "the IEC 104 outstation", cfg.iec104),
        ("opcua", "the OPC UA server", cfg.opcua),
    )
    for section, name, value in sections:
        if value.enabled:
            continue
        default = type(value)()
        changed = [
            f.name
            for f in dataclasses.fields(value)
            if f.name != "enabled" and getattr(value, f.name) != getattr(default, f.name)
        ]
        if changed:
            out.append(
                f"[{section}] sets {', '.join(changed)} but not enabled = true: {name} is "
                f"off; set [{section}] enabled = true to turn it on"
            )
    return out


def packet_rings(plan: ServePlan) -> dict[str, PacketRing]:
    """Per live camera with a live detection substream, the ring its full stream is kept in
    (encoded, never decoded) unless [input] full_streams = "decode"; sized for one alarm's
    clip (clip_pre_s + clip_post_s, and some seconds for the keyframe before)."""
    cfg = plan.config
    if cfg.input.full_streams != "copy" or cfg.input.detection == "nodes":
        return {}
    s = plan.clips or ClipSettings()
    keep_s = s.clip_pre_s + s.clip_post_s + 5.0
    return {
        name: PacketRing(keep_s, s.clip_buffer_bytes)
        for name, src, sub in zip(plan.rig.names, plan.sources, plan.detect_sources, strict=True)
        if sub and is_stream(str(src)) and is_stream(str(sub))
    }
