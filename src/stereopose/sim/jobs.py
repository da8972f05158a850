"""Simulated switching and maintenance jobs for the tickets (stereopose.tickets): an operator
walking to each step's position and reaching for its target, a supervisor following, and
the deviations each variant scripts, so tests and benchmarks know the truth.

The room is sim.scene's 12 x 8 m; three bays stand against the wall y = 0 at x = 3, 6 and 9
m. Bay k has an energized panel `bay{k}_panel` (0.5 m deep, 0-2.2 m high, 0.15 m approach
margin), the handle of its switch `bay{k}_handle` in front of the panel (the step's target:
0.9 x 0.55 m, 1.0-1.8 m high) and the place to operate it from, `bay{k}_front` (a 0.7 x 0.6 m
work area). Variants (VARIANTS):

- compliant: the operation ticket's three steps in order, each from its position, the
  supervisor 1.2-1.6 m from the operator all along;
- swapped: steps 1, 3, 2 (step 3 out of order);
- skipped: steps 1 and 3 (step 3 out of order, step 2 missed);
- wrong_bay: step 2 done standing beside its position, reaching across (wrong position);
- supervisor_leaving: the supervisor walks away for 14-18 s during step 2 (absent);
- neighbour_live: a work ticket isolating bay 2's panel: the worker touches it twice (no
  alarm with the ticket), does the step, then touches bay 3's live panel once (an alarm).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from stereopose.fence import Site, Zone
from stereopose.sim.behaviour import Take, _Script, acted_scene
from stereopose.sim.detections import DetectorNoise
from stereopose.sim.postures import Actor
from stereopose.sim.scene import Scene, ScenePreset, make_rig
from stereopose.tickets.ticket import Ticket, TicketStep

__all__ = ["VARIANTS", "JobScene", "job_site", "simulate_job"]

VARIANTS = (
    "compliant",
    "swapped",
    "skipped",
    "wrong_bay",
    "supervisor_leaving",
    "neighbour_live",
)
BAYS_X = (3.0, 6.0, 9.0)
ROOM = (12.0, 8.0, 4.0)
SUPERVISE_M = 3.0
ABSENT_S = 8.0
FACING = -90.0  # towards the wall y = 0 (degrees from world +x)
HANDLE_Y = 0.95  # the handle zone's middle, metres from the wall
STAND_Y = 1.55  # where the operator stands to operate


def _box(x0: float, x1: float, y0: float, y1: float) -> np.ndarray:
    return np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], dtype=np.float64)


def job_site(fps: float = 25.0) -> Site:
    """The three bays' zones (see the module)."""
    zones = []
    for k, x in enumerate(BAYS_X, start=1):
        zones.append(
            Zone(
                f"bay{k}_panel",
                "energized",
                _box(x - 0.8, x + 0.8, 0.0, 0.5),
                (0.0, 2.2),
                margin_m=0.15,
            )
        )
        zones.append(
            Zone(f"bay{k}_handle", "work_area", _box(x - 0.45, x + 0.45, 0.7, 1.25), (1.0, 1.8))
        )
        zones.append(
            Zone(f"bay{k}_front", "work_area", _box(x - 0.35, x + 0.35, 1.25, 1.85), (0.0, 2.5))
        )
    return Site(tuple(zones), fps)


def operation_ticket() -> Ticket:
    """The operation ticket of the jobs: bay 2's breaker, bay 1's disconnector, bay 3's
    earthing switch, in that order, under supervision."""
    steps = (
        ("open breaker QF2", 2),
        ("open disconnector QS1", 1),
        ("close earthing switch QE3", 3),
    )
    return Ticket(
        id="OT-SIM",
        title="Bays 1-3: from service to maintenance",
        kind="operation",
        steps=tuple(
            TicketStep(name, f"bay{b}_front", f"bay{b}_handle", hold_s=1.0, max_s=120.0)
            for name, b in steps
        ),
        supervisor="auto",
        supervise_m=SUPERVISE_M,
        absent_s=ABSENT_S,
        lone_s=None,
    )


def work_ticket() -> Ticket:
    """The work ticket: bay 2 isolated and earthed, its handle checked, no supervisor."""
    return Ticket(
        id="WT-SIM",
        title="Bay 2: maintenance",
        kind="work",
        steps=(TicketStep("check bay 2", "bay2_front", "bay2_handle", hold_s=1.0, max_s=120.0),),
        isolated=("bay2_panel",),
        lone_s=None,
    )


@dataclass(frozen=True, eq=False)
class JobScene:
    """A simulated job: the scene, its site and ticket, and its truth: the deviations the
    script holds (type, step or None), the steps it does, the live touches (zone names)."""

    scene: Scene
    site: Site
    ticket: Ticket
    variant: str
    deviations: tuple[tuple[str, str | None], ...]
    steps_done: tuple[str, ...]
    live_touches: tuple[str, ...]
    isolated_touches: int

    @property
    def duration_s(self) -> float:
        return self.scene.num_frames / self.scene.fps


def _operate(s: _Script, bay: int, hold_s: float, beside: float = 0.0) -> None:
    """Walk to bay `bay`'s position (or `beside` metres to its side, reaching across), reach
    the handle for hold_s, step back."""
    x = BAYS_X[bay - 1]
    if beside:
        stand = np.array([x + beside, STAND_Y - 0.15])
        d = np.array([x, HANDLE_Y]) - stand
        heading = float(np.arctan2(d[1], d[0]))
    else:
        stand, heading = np.array([x, STAND_Y]), np.radians(FACING)
    s.walk(stand)
    s.turn(heading)
    s.add("stand", hold_s, reach=(0.55, 0.55), ease_s=0.6)
    s.add("stand", 1.0, ease_s=0.6)


def _touch(s: _Script, bay: int, hold_s: float = 1.5) -> None:
    """Reach into bay `bay`'s panel from close in front of it."""
    x = BAYS_X[bay - 1]
    s.walk(np.array([x + 0.4, 1.05]))
    s.turn(np.radians(FACING))
    s.add("stand", hold_s, reach=(0.55, 0.55), ease_s=0.6)
    s.add("stand", 1.0, ease_s=0.6)
    s.walk(np.array([x + 0.4, 2.2]))


def _follow(sup: _Script, op: _Script, rng: np.random.Generator, leave: tuple | None) -> None:
    """The supervisor 1.2-1.6 m behind and beside the operator's positions, in step with the
    operator's script; leave: (after the operator's act n, seconds away)."""
    stops = [a for a in op.acts if a.kind == "stand" and a.reach[0] > 0]
    for n, a in enumerate(stops):
        side = 1.0 if a.start[0] < 8.0 else -1.0
        spot = np.array([a.start[0] + side * float(rng.uniform(0.9, 1.2)), a.start[1] + 0.9])
        if sup.t < a.t0 - 3.0:
            sup.add("stand", a.t0 - 3.0 - sup.t, ease_s=0.6)
        sup.walk(spot)
        if leave is not None and n == leave[0]:
            sup.walk(np.array([6.0, 7.0]))
            sup.add("stand", leave[1], ease_s=0.6)
            sup.walk(spot)
        back = np.arctan2(a.start[1] - spot[1], a.start[0] - spot[0])
        sup.turn(float(back))
    sup.add("stand", max(op.t - sup.t, 0.0) + 3.0, ease_s=0.6)


def _scripts(
    variant: str, rng: np.random.Generator
) -> tuple[_Script, _Script | None, list[tuple[str, str | None]], tuple[str, ...], list[str], int]:
    """The operator's and the supervisor's scripts and the truth of `variant`."""
    op = _Script(rng, np.array([6.0, 5.0]), np.radians(FACING))
    op.add("stand", 1.5, ease_s=0.6)
    hold = 2.5
    names = [s.name for s in operation_ticket().steps]
    dev: list[tuple[str, str | None]] = []
    live: list[str] = []
    touches = 0
    order = {"swapped": (2, 1, 3), "skipped": (2, 3)}.get(variant, (2, 1, 3))
    bays = {1: 2, 2: 1, 3: 3}  # step -> bay
    steps = {"swapped": (1, 3, 2), "skipped": (1, 3)}.get(variant, (1, 2, 3))
    if variant == "neighbour_live":
        _touch(op, 2)
        _operate(op, 2, hold)
        _touch(op, 2)
        _touch(op, 3)
        touches, live = 2, ["bay3_panel"]
        done = ("check bay 2",)
        op.add("stand", 2.0, ease_s=0.6)
        return op, None, dev, done, live, touches
    del order
    for st in steps:
        beside = 0.75 if variant == "wrong_bay" and st == 2 else 0.0
        _operate(op, bays[st], hold, beside)
        if beside:
            dev.append(("step_wrong_position", names[st - 1]))
    if variant in ("swapped", "skipped"):
        dev.append(("step_out_of_order", names[2]))
    op.walk(np.array([6.0, 5.0]))
    op.add("stand", 3.0, ease_s=0.6)
    sup = _Script(rng, np.array([7.2, 5.6]), np.radians(FACING))
    leave = None
    if variant == "supervisor_leaving":
        leave = (1, float(rng.uniform(14.0, 18.0)))
        dev.append(("supervisor_absent", None))
    _follow(sup, op, rng, leave)
    done = tuple(names[st - 1] for st in steps)
    return op, sup, dev, done, live, touches


def simulate_job(
    variant: str = "compliant",
    seed: int = 0,
    difficulty: str = "easy",
    fps: float = 25.0,
    *,
    num_cameras: int | None = None,
    noise: DetectorNoise | None = None,
) -> JobScene:
    """A job of `variant` (VARIANTS); the rig, cameras and detector errors of sim.scene's
    `difficulty`."""
    if variant not in VARIANTS:
        raise ValueError(f"unknown job {variant!r}; expected one of {', '.join(VARIANTS)}")
    preset = ScenePreset.preset(difficulty)
    noise = DetectorNoise.preset(difficulty) if noise is None else noise
    C = preset.num_cameras if num_cameras is None else int(num_cameras)
    rig = make_rig(C, np.random.default_rng(seed), ROOM)
    op, sup, dev, done, live, touches = _scripts(variant, np.random.default_rng([seed, 7]))
    scripts = [op] if sup is None else [op, sup]
    duration_s = max(s.t for s in scripts) + 1.0
    for s in scripts:
        if s.t < duration_s + 1.0:
            s.add("stand", duration_s + 1.0 - s.t, ease_s=0.6)
    floor = ROOM[:2]
    actors = []
    for n, s in enumerate(scripts):
        wrng = np.random.default_rng([seed, 8, n])
        actors.append(
            Actor(
                height=float(wrng.uniform(1.65, 1.85)),
                step_hz=float(wrng.uniform(1.7, 1.9)),
                phase0=float(wrng.uniform(0.0, 2.0 * np.pi)),
                acts=tuple(s.acts),
                room=floor,
                seed=int(wrng.integers(2**31)),
            )
        )
    rng = np.random.default_rng([seed, 9])
    take = Take(fps, round(duration_s * fps), ROOM, difficulty, seed)
    scene = acted_scene(actors, rig, noise, take, rng)
    ticket = work_ticket() if variant == "neighbour_live" else operation_ticket()
    return JobScene(
        scene=scene,
        site=job_site(fps),
        ticket=ticket,
        variant=variant,
        deviations=tuple(dev),
        steps_done=done,
        live_touches=tuple(live),
        isolated_touches=touches,
    )
