"""The frame loop, shared by every run: source -> detection -> 3D stage -> fences and
behaviour rules -> sinks.

``reconstruct`` (keypoint files), ``run`` and ``demo`` (cameras) and the service build a
source, a 3D stage and their sinks, and hand them to `FrameLoop`. Per frame it times each
stage apart (the source's reading, detection, 3D, fences, and each sink under its own stage),
calls `on_step(done, total, fps)`, and stops after the current frame when `stop` is set or on
SIGINT (at once while it waits for the source, and at a second Ctrl-C: pipeline.interrupt).
Whatever ends the loop (the source's end, `stop`, Ctrl-C, an error), every sink is closed, so
what was written stays readable.

Each step's time t comes from the source (recorded: frame / fps; live cameras: when the frames
arrived) and goes with the step to the 3D stage (the tracker's prediction and its max_lost_s),
the fences (debounce, dwell, event times) and every sink record.

Nothing in the loop keeps anything per frame: the summary holds running aggregates.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Protocol

import numpy as np

from stereopose.behaviour.posture import PostureSettings
from stereopose.behaviour.rules import BehaviourMonitor
from stereopose.config import Config
from stereopose.errors import IncompleteOutputError
from stereopose.fence import FenceMonitor, Site
from stereopose.io.sinks import FrameResult, Sink
from stereopose.io.sinks.base import unwrapped
from stereopose.io.sinks.files import TwoWaySink
from stereopose.io.summary import RunSummary
from stereopose.pipeline.interrupt import Interrupt
from stereopose.pipeline.outputs import Outputs, open_outputs
from stereopose.pipeline.stage3d import Stage3D
from stereopose.tickets.ticket import Ticket
from stereopose.types import Event, People2D, People3D, Rig
from stereopose.zones.state_log import StateLogFile

if TYPE_CHECKING:
    from stereopose.pipeline.incidents import IncidentStep

logger = logging.getLogger(__name__)

OnStep = Callable[[int, "int | None", float], None]


@dataclass(frozen=True, eq=False)
class SourceStep:
    """What a source gives per step: the frame number, its time t (seconds on the source's
    clock, increasing from step to step), each camera's 2D people (None: the source's `detect`
    finds them in `images`), and each camera's image (cameras only; None where a camera has no
    frame at this step)."""

    frame: int
    t: float
    people2d: Mapping[str, People2D] | None
    images: Mapping[str, np.ndarray | None] | None = None


class Source(Protocol):
    """Where frames come from: keypoint files or cameras (pipeline.sources).

    stages: the summary's stages for a run of this source; the first one is the time spent
    getting the next step. total: number of steps, None when unknown (live).
    """

    @property
    def cameras(self) -> tuple[str, ...]: ...

    @property
    def stages(self) -> tuple[str, ...]: ...

    @property
    def fps(self) -> float: ...

    @property
    def live(self) -> bool: ...

    @property
    def total(self) -> int | None: ...

    def __iter__(self) -> Iterator[SourceStep]: ...

    def detect(self, step: SourceStep) -> Mapping[str, People2D]: ...

    def finish(self, summary: RunSummary) -> None:
        """What the source knows of the run, into the summary (camera statistics, files
        skipped)."""

    def tracked(self, people: People3D) -> None:
        """Each step's 3D people, given back: a source that detects in regions looks next
        where they are (pipeline.sources.Cameras); others do nothing."""


class Stage(Protocol):
    """The 3D stage (pipeline.stage3d.Stage3D)."""

    tracking: bool

    def load(self) -> float: ...

    def step(
        self, frame: int, people2d: Mapping[str, People2D], t: float | None = None
    ) -> People3D:
        """The output people of `frame`, at time t (None: frame / fps), stamped with t."""
        ...

    def trajectories(self) -> list: ...


class StepRules(Protocol):
    """A step's rules as the frame loop asks them: `step` returns the step's events (zones,
    behaviour; with their incidents where the rules keep an incident book: IncidentStep) and
    the people's postures (None: no posture rules), given to every sink in FrameResult.
    When `ends_with_source` is true (a ticket active to the last frame), `finish(t, frame)`
    gives the events of the input's end, added to the last step's."""

    def step(self, t: float, frame: int, people: People3D) -> tuple[list[Event], dict | None]: ...

    @property
    def ends_with_source(self) -> bool: ...

    def finish(self, t: float, frame: int) -> list[Event]: ...


class FrameLoop:
    """One run's frame loop. `run()` once: it returns the summary, every sink closed.

    sinks: closed in their order at the end (pipeline.outputs.open_outputs puts the summary
    and the report last). rules: the step's rules (StepRules: a pipeline.step_rules.StepChain
    alone, or an IncidentStep with the incident book; None: no site).
    """

    def __init__(
        self,
        source: Source,
        stage: Stage,
        sinks: Sequence[Sink],
        summary: RunSummary,
        *,
        rules: StepRules | None = None,
        on_step: OnStep | None = None,
        stop: threading.Event | None = None,
    ) -> None:
        self.source, self.stage, self.sinks = source, stage, list(sinks)
        self.summary, self.rules = summary, rules
        self.on_step = on_step
        self.stop = stop or threading.Event()
        self.interrupt = Interrupt(self.stop)
        for sink in self.sinks:
            self.summary.seconds.setdefault(sink.stage, 0.0)

    def run(self) -> RunSummary:
        s = self.summary
        error: BaseException | None = None
        start = time.perf_counter()
        self.interrupt.stop = self.stop  # `stop` may be replaced before run
        with self.interrupt.installed():
            try:
                s.load_s_3d = self.stage.load()
                start = time.perf_counter()
                self._frames(start)
                s.interrupted = self.stop.is_set()
            except KeyboardInterrupt:
                s.interrupted = True
            except BaseException as e:
                s.error = f"{type(e).__name__}: {e}"
                error = e
            finally:
                s.wall_s = time.perf_counter() - start
                failed = self._close()
        if error is not None:
            raise error
        if failed is not None:
            raise failed
        if s.interrupted:
            logger.warning("run interrupted after %d frames; outputs closed", s.frames)
        return s

    def _frames(self, start: float) -> None:
        sec = self.summary.seconds
        first = self.source.stages[0]
        total = self.source.total
        it = iter(self.source)
        # the input's end ends something (a ticket active to the last frame): each step is
        # read one ahead, so the last one is known as it is processed
        ahead = self.rules is not None and self.rules.ends_with_source
        upcoming = None
        done = 0
        while not self.stop.is_set():
            t0 = time.perf_counter()
            with self.interrupt.wait():
                step = next(it, None) if upcoming is None else upcoming
                upcoming = next(it, None) if ahead and step is not None else None
            t1 = time.perf_counter()
            sec[first] += t1 - t0
            if step is None:
                break
            people2d = step.people2d
            if people2d is None:
                people2d = self.source.detect(step)
                t0, t1 = t1, time.perf_counter()
                sec["detect"] += t1 - t0
            people3d = self.stage.step(step.frame, people2d, step.t)
            self.source.tracked(people3d)  # the tracks back to detection: the next regions
            t2 = time.perf_counter()
            sec["3d"] += t2 - t1
            events, postures = [], None
            if self.rules is not None:
                events, postures = self.rules.step(step.t, step.frame, people3d)
                if ahead and upcoming is None:  # the last step
                    events = [*events, *self.rules.finish(step.t, step.frame)]
            t3 = time.perf_counter()
            sec["fences"] += t3 - t2
            result = FrameResult(
                step.frame, step.t, people2d, people3d, events, step.images, postures
            )
            for sink in self.sinks:
                sink.write(result)
                t4 = time.perf_counter()
                sec[sink.stage] += t4 - t3
                t3 = t4
            done += 1
            if self.on_step is not None:
                elapsed = time.perf_counter() - start
                self.on_step(done, total, done / elapsed if elapsed > 0 else 0.0)

    def _close(self) -> BaseException | None:
        """Close every sink in order, the run's figures filled in first; the first error."""
        s = self.summary
        failed: BaseException | None = None
        try:
            self.source.finish(s)
            if self.stage.tracking:
                s.trajectories = self.stage.trajectories()
        except Exception as e:  # the outputs are closed all the same
            logger.exception("finishing the run's figures failed")
            failed = e
        s.two_way_frames = sum(
            w.frames_kept for sink in self.sinks if isinstance(w := unwrapped(sink), TwoWaySink)
        )
        for sink in self.sinks:
            try:
                s.outputs.extend(sink.close())
            except BaseException as e:  # close the others all the same
                logger.exception("closing %s failed", type(sink).__name__)
                failed = failed or e
        return failed


def behaviour_monitor(site: Site | None, config: Config) -> BehaviourMonitor | None:
    """The monitor of the site's behaviour rules and postures (None: no site, or neither
    [[rules]] nor [postures] in it)."""
    if site is None or (not site.rules and site.postures is None):
        return None
    settings = site.postures or PostureSettings()
    return BehaviourMonitor(
        site.rules, site.zones, config.fps, config.tracking.max_lost_s, settings
    )


def run_frames(
    rig: Rig,
    config: Config,
    source: Source,
    outputs: Outputs,
    site: Site | None,
    *,
    calib_path: str = "",
    label: str = "",
    on_events: Callable[[list[Event]], None] | None = None,
    stop: threading.Event | None = None,
    on_step: Callable[[int, int | None, float], None] | None = None,
    ticket: Ticket | None = None,
    zone_states: StateLogFile | None = None,
    out_dir: Path | None = None,
    config_path: Path | None = None,
) -> RunSummary:
    """A whole run: the 3D stage (its compiled loops loaded first), the fences of `site` and
    the sinks of `outputs` around `source`, through the frame loop; the run's summary.

    label: what the run reads (the event log's `runs.source`); out_dir, config_path: the
    RunSummary's. The outputs' needs (pipeline.outputs.
    check_outputs) are checked by the caller, before anything is written. An output that failed
    during the run (pipeline.outputs.open_outputs) raises IncompleteOutputError at the end,
    every frame processed and the other outputs complete; it holds the summary.
    """
    stage = Stage3D(rig, config, record=outputs.two_way, calib_path=calib_path)
    summary = RunSummary(
        rig.names,
        source.stages,
        config.reconstruction.triangulation.mode,
        stage.tracking,
        live=source.live,
        fps_input=source.fps,
        out_dir=out_dir,
        config_path=config_path,
    )
    fences = FenceMonitor(site, config.fps, config.tracking.max_lost_s) if site else None
    sinks = open_outputs(
        outputs,
        rig=rig,
        config=config,
        summary=summary,
        stage=stage,
        site=site,
        source=label,
        on_events=on_events,
    )
    behaviour = behaviour_monitor(site, config)
    if site is not None and fences is not None:
        # the service's incidents: the same book, ids and priorities
        incidents = run_incidents(site, fences, behaviour, sinks, ticket, zone_states)
        loop = FrameLoop(source, stage, sinks, summary, rules=incidents, on_step=on_step, stop=stop)
    else:
        loop = FrameLoop(source, stage, sinks, summary, on_step=on_step, stop=stop)
    summary = loop.run()
    if summary.failed_outputs:  # the work is done, but not all of it is kept: exit code 3
        raise IncompleteOutputError(summary.failed_outputs, summary.outputs, summary)
    return summary


def run_incidents(
    site: Site,
    fences: FenceMonitor,
    behaviour: BehaviourMonitor | None,
    sinks: Sequence[Sink],
    ticket: Ticket | None = None,
    zone_states: StateLogFile | None = None,
) -> IncidentStep:
    """The incident book of `serve` over a run's events (pipeline.incidents): each
    alarm-level event stamped with its incident's id and priority as the service would (ids
    from 1, the run's own), the incidents' records stored in the run's event log. ticket:
    active from the first step to the last (its ticket_completed at the last); zone_states:
    the recorded job's switching log (zones.state_log; None: every zone live)."""
    from stereopose.alarms import IncidentBook
    from stereopose.alarms.priority import AlarmSettings
    from stereopose.io.sinks import SqliteSink
    from stereopose.pipeline.incidents import IncidentStep
    from stereopose.pipeline.step_rules import step_chain
    from stereopose.tickets import TicketDesk

    db = next((u for s in sinks if isinstance(u := unwrapped(s), SqliteSink)), None)
    desk = None
    if ticket is not None:
        desk = TicketDesk(site.zones)
        desk.add(ticket)
        desk.start(ticket.id, "run")
    # a run takes no operator's act and is not asked for its alarm figures: no clock to read
    return IncidentStep(
        IncidentBook(AlarmSettings.from_site(site)),
        step_chain(
            fences,
            behaviour=behaviour,
            tickets=desk,
            zone_log=zone_states.rule(site.zones, fences) if zone_states is not None else None,
        ),
        holding=fences,
        outputs=[db.write_changes] if db is not None else [],
        clock=lambda: 0.0,
    )
