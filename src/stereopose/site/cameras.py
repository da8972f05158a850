"""Where `serve`'s people come from: the cameras opened on the service's clock (a camera that
has not delivered yet is reported, never waited for), detection on its own thread here,
always on the newest frames (recorded: every step), or the detection nodes' people, grouped
by capture time (nodes.fusion); and each camera's nominal rate, against which its health is
judged."""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass

from stereopose.config import Config
from stereopose.detection.base import PoseDetector
from stereopose.fence import Site
from stereopose.io.cameraset import CameraSet
from stereopose.io.packets import PacketRing
from stereopose.io.source import Clock
from stereopose.nodes.fusion import NodeInput
from stereopose.pipeline.pipelined import PipelinedCameras
from stereopose.pipeline.sources import detecting_cameras
from stereopose.site.plan import ServePlan
from stereopose.site.service import SiteService
from stereopose.site.site_parts import hazards_watch, scans_watch
from stereopose.types import Rig

__all__ = ["PeopleSource", "nominal_rates", "open_cameras", "people_source"]


def nominal_rates(cams: CameraSet) -> dict[str, tuple[float | None, float | None]]:
    """Per camera (the rate the service should process it at, its own rate): its frame rate,
    or detect_fps when lower; None while not known (a live stream not yet connected)."""
    out = {}
    for s in cams.sources:
        own = float(s.fps) if s.fps else None
        nominal = min(own, cams.detect_fps) if own and cams.detect_fps else own
        out[s.name] = (nominal, own)
    return out


def open_cameras(
    plan: ServePlan, packets: dict[str, PacketRing], clock: Clock
) -> CameraSet | NodeInput:
    """The cameras, or the detection nodes' people, on the service's clock (its t = 0)."""
    cfg = plan.config
    if cfg.input.detection == "nodes":  # the cameras' people from the detection nodes
        assert plan.mqtt is not None  # plan_serve: [mqtt] host is set
        i = cfg.input
        return NodeInput(
            plan.mqtt,
            plan.rig,
            fps=i.detect_fps or i.fps or cfg.fps,
            window_s=i.node_window_s,
            wait_s=i.node_wait_s,
            clock_tolerance_s=i.node_clock_tolerance_s,
            picture_scale=i.node_picture_scale,
            clock=clock,
        )
    # a service starts at once however long its cameras take: the loop goes on in heartbeats
    # and the camera watch raises camera_down for each camera that has not delivered
    return CameraSet(
        list(plan.sources),
        list(plan.rig.names),
        cfg.input.sync,
        cfg.input.fps,
        None,
        open_timeout_s=cfg.input.open_timeout_s,
        first_frame_timeout_s=None,
        loop=[c.loop for c in cfg.cameras],
        detect=[d or None for d in plan.detect_sources],
        detect_fps=cfg.input.detect_fps,
        wait_first_frame=False,
        packets=packets,
        wall_clock=True,
        decoders=cfg.input.decoders,
        clock=clock,
    )


@dataclass(frozen=True)
class PeopleSource:
    """Where the steps' people come from (`steps`), each camera's nominal rates (`rates`),
    and what of it follows a new rig (`rig_followers`: the tracks' regions in the new views)
    and a new site (`site_followers`: the regions' scans, the carried steps' hazards)."""

    steps: PipelinedCameras | NodeInput
    rates: Callable[[], dict]
    rig_followers: tuple[Callable[[Rig], None], ...] = ()
    site_followers: tuple[Callable[[Site], None], ...] = ()


def people_source(
    plan: ServePlan,
    service: SiteService,
    cams: CameraSet | NodeInput,
    detector: PoseDetector | None,
    cfg: Config,
) -> PeopleSource:
    """Where the steps' people come from: the detection nodes' people grouped by capture
    time, or detection on its own thread here, always on the newest frames (recorded: every
    step). Each is reported (site.report)."""
    rig = plan.rig
    if isinstance(cams, NodeInput):
        service.report.watch_nodes(cams)  # reported; its receiver watched (run_parts)
        # the nodes' carried steps
        return PeopleSource(
            cams, cams.rates, site_followers=(hazards_watch(cams, service.power, plan.site),)
        )
    assert detector is not None  # made in this process unless the nodes detect
    cameras = detecting_cameras(cams, rig, detector, cfg.detector)  # scans: site_followers
    regions, light = cameras.regions, cameras.light
    assert light is not None  # detecting cameras watch their light
    service.report.watch_light(light)  # each camera's day or night
    pipelined = PipelinedCameras(cameras)
    service.report.watch_pipeline(pipelined)
    on_site: list[Callable[[Site], None]] = []
    if regions is not None:  # figures by camera in status, /metrics and the console
        service.report.watch_regions(regions)
        service.hub.show_regions(regions.view)
        on_site.append(scans_watch(regions, rig, plan.site))
    if cameras.carry is not None:
        on_site.append(hazards_watch(cameras, service.power, plan.site))
    return PeopleSource(
        pipelined,
        functools.partial(nominal_rates, cams),
        rig_followers=(cameras.set_rig,),  # the tracks' regions in the new views
        site_followers=tuple(on_site),
    )
