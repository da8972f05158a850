"""What a running `serve` reports about itself, apart from the parts it runs (site.service):
the health state (site.health.state: /api/health, /metrics, the console), the outputs that
failed (each stopped alone), and each part's figures, put together as `status.json`
(`snapshot`). A part is watched once, as it is made (`watch_*`): its queue, its health, its
figures."""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING

from stereopose.io.sinks.base import Guarded
from stereopose.io.sinks.health import AlarmOutput
from stereopose.site.health.state import ServiceState
from stereopose.site.http.api.health import health_of
from stereopose.site.parts import output_health

if TYPE_CHECKING:
    from stereopose.detection import Choice
    from stereopose.detection.light import LightWatch
    from stereopose.detection.regional import RegionDetector
    from stereopose.nodes.fusion import NodeInput
    from stereopose.pipeline.pipelined import PipelinedCameras

__all__ = ["StatusReport"]


class StatusReport:
    """See the module. state: the service's health state."""

    def __init__(self, state: ServiceState) -> None:
        self.state = state
        self.failed: dict[str, str] = {}  # output -> why it stopped (io.sinks.base.Guarded)
        # status.json's parts: each one's figures (None: left out now)
        self.probes: dict[str, Callable[[], Mapping[str, object] | None]] = {}
        self.elsewhere: Callable[[], dict[str, float]] | None = None  # stages off the loop

    def watch(self, name: str, figures: Callable[[], Mapping[str, object] | None]) -> None:
        """A part's figures in status.json under `name` (None from it: left out then); one
        part per name."""
        if name in self.probes:
            raise ValueError(f"status.json: {name!r} is watched already")
        self.probes[name] = figures

    def watch_output(self, out: AlarmOutput, sink: Guarded) -> None:
        """An alarm output under its output_name, as the frame loop writes it (`sink`, its
        Guarded wrapper: an output that fails stops alone): the health state's queues and
        outputs (so /api/health and /metrics), `status.json`'s figures."""
        name = out.output_name
        self.state.register_queue(name, out.queued, lambda: out.dropped)
        self.state.register_output(name, output_health(out, sink))
        self.watch(name, out.figures)

    def watch_detector(self, choice: Choice | None) -> None:
        """What detects, and why (make_detector's choice; None: none, or made otherwise)."""
        if choice is not None:
            self.watch("detector", choice.as_dict)

    def watch_light(self, light: LightWatch) -> None:
        """Each camera's light (day, night, black, blinded) in status.json, /metrics,
        /api/cameras and the console."""
        self.watch("light", light.figures)
        self.state.register_light(light.figures)

    def watch_nodes(self, nodes: NodeInput) -> None:
        """The nodes' camera-frames waiting for their step as a queue of the health state
        (late, over-full and refused ones as its drops); the nodes' figures in status; each
        camera's light as the nodes see it."""
        from stereopose.nodes.node_state import nodes_light

        self.state.register_queue("nodes", nodes.waiting, nodes.lost)
        self.state.register_light(lambda: nodes_light(nodes.report()))
        self.watch("nodes", nodes.report)

    def watch_pipeline(self, pipelined: PipelinedCameras) -> None:
        """The detection hand-over as a queue of the health state; its figures in status;
        detection's time, spent off the frame loop, in the stages."""
        stats = pipelined.stats
        self.elsewhere = lambda: {"detect": stats.detect_s}
        self.state.register_queue(
            "detection", lambda: len(pipelined.handover), lambda: pipelined.handover.dropped
        )
        self.watch("pipeline", stats.figures)

    def watch_regions(self, regions: RegionDetector) -> None:
        """Detection in regions' figures by camera in status and /metrics."""
        self.state.register_regions(regions.report)
        self.watch("regions", regions.report)

    def snapshot(self) -> dict:
        """status.json: the health answer, the outputs that failed, each part's figures."""
        doc = health_of(self.state.snapshot()).model_dump()
        doc["written_at"] = time.time()
        doc["failed_outputs"] = dict(self.failed)
        for name, probe in list(self.probes.items()):
            try:
                figures = probe()
            except Exception as e:  # a part's figures missing never stops the status
                figures = {"error": str(e)}
            if figures is not None:  # None: nothing of its own to report now
                doc[name] = figures
        return doc
