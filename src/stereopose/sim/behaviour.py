"""Simulated substations for the behaviour rules: workers who fall (and stay down or get up),
kneel, squat, sit, bend, stoop and reach, and who work at energized panels alone or in pairs,
from the right place or not.

Three kinds of scene, all in the 12 x 8 m room of sim.scene with 3 panels on its walls:

- "falls": each worker walks between activities (stand, reach overhead, bend, stoop, squat,
  kneel on one or both knees, sit on a box or on the floor, each entered over 0.8-3 s) and
  falls once, walking or from an upright activity: stays down to the end, lies 3-8 s longer
  than `down_s` and gets up, or scrambles up again within about a second (no alarm due); the
  scripted falls are kept (Fall) for the latency;
- "routine": the same activities without falls, for false alarms per worker-hour;
- "work": jobs one after the other at the panels, each by one worker (a lone worker, or a short
  look of a few seconds) or two (the second within 1.0-1.3 m); the one at the panel reaches
  into it standing or kneeling from the work area facing it, or faces 55-90 degrees away, or
  stands beside the work area; the others wait in the middle of the room (about 2 m or more
  from any panel's approach), standing a few seconds and stepping elsewhere.

Each panel is an energized zone (1.6 x 0.6 m, 0-2.2 m high, 0.5 m approach margin) against a
wall with a 0.8 x 0.9 m work area in front of it; `site_rules` are the rules the benchmark
applies. The ground truth of the rules is the same monitor on the true joints (truth_events).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, TypedDict, Unpack

import numpy as np

from stereopose.fence import Site, Zone
from stereopose.sim.detections import DetectorNoise, detect
from stereopose.sim.motion import keep_apart
from stereopose.sim.postures import Act, Actor, Fall
from stereopose.sim.scene import MIN_APART_M, Scene, ScenePreset, make_rig
from stereopose.skeleton import NUM_JOINTS

if TYPE_CHECKING:
    from stereopose.types import Rig

SCENE_KINDS = ("falls", "routine", "work")
ACTIVITIES = ("stand", "reach", "bend", "stoop", "squat", "kneel", "kneel2", "sit", "sit_floor")
UPRIGHT = ("stand", "reach", "bend", "stoop")  # what a worker falls from
PANEL_W, PANEL_D, AREA_W, AREA_D = 1.6, 0.6, 0.8, 0.9
WAIT = ((4.5, 3.5), (7.5, 4.5))  # where workers without a job wait (x0, y0), (x1, y1)


@dataclass(frozen=True)
class Panel:
    """An energized panel against a wall: its zone, its work area and the direction (degrees
    from world +x) a worker at it faces; stand: the floor point of the right place to work."""

    energized: Zone
    work_area: Zone
    facing_deg: float
    stand: tuple[float, float]
    side: tuple[float, float]  # unit vector along the panel's face


def _rect(p: np.ndarray, n: np.ndarray, c0: float, c1: float, half: float) -> np.ndarray:
    """Rectangle from c0 to c1 along the wall normal n from wall point p, half wide."""
    t = np.array([-n[1], n[0]])
    return np.array(
        [p + c0 * n - half * t, p + c0 * n + half * t, p + c1 * n + half * t, p + c1 * n - half * t]
    )


def make_panels(
    rng: np.random.Generator, room: tuple[float, float], count: int = 3
) -> tuple[Panel, ...]:
    """`count` panels on different walls, 1.5 m or more from the corners."""
    W, D = room
    lo = 1.5 + PANEL_W / 2
    out = []
    for k, wall in enumerate(rng.permutation(4)[:count]):
        # p: the middle of the panel's back on the wall; n: the wall's inward normal
        if wall in (0, 2):
            p = np.array([rng.uniform(lo, W - lo), 0.0 if wall == 0 else D])
            n = np.array([0.0, 1.0 if wall == 0 else -1.0])
        else:
            p = np.array([W if wall == 1 else 0.0, rng.uniform(lo, D - lo)])
            n = np.array([-1.0 if wall == 1 else 1.0, 0.0])
        energized = Zone(
            f"panel_{k}",
            "energized",
            _rect(p, n, 0.0, PANEL_D, PANEL_W / 2),
            (0.0, 2.2),
            margin_m=0.5,
        )
        area = _rect(p, n, PANEL_D, PANEL_D + AREA_D, AREA_W / 2)
        out.append(
            Panel(
                energized=energized,
                work_area=Zone(f"work_{k}", "work_area", area, (0.0, 2.5)),
                facing_deg=float(np.degrees(np.arctan2(-n[1], -n[0]))),
                stand=tuple(p + (PANEL_D + 0.4) * n),
                side=(float(-n[1]), float(n[0])),
            )
        )
    return tuple(out)


def site_rules(panels: Sequence[Panel], down_s: float = 3.0, lone_s: float = 10.0) -> list[dict]:
    """The `[[rules]]` tables the benchmark applies to a scene with these panels (as a site
    file holds them; behaviour.definitions.parse_rules reads them)."""
    rules = [
        {"name": "man_down", "type": "person_down", "down_s": down_s},
        {
            "name": "two_person",
            "type": "lone_worker",
            "zones": [p.energized.name for p in panels],
            "buddy_m": 2.0,
            "lone_s": lone_s,
        },
        {"name": "still", "type": "immobile", "immobile_s": 30.0},
        {"name": "overhead", "type": "overreach", "max_height_m": 2.1},
    ]
    for p in panels:
        rules.append(
            {
                "name": f"position_{p.energized.name}",
                "type": "work_position",
                "zone": p.work_area.name,
                "facing_deg": round(p.facing_deg, 3),
                "tolerance_deg": 30.0,
                "energized": [p.energized.name],
            }
        )
    return rules


@dataclass(frozen=True, eq=False)
class BehaviourScene:
    """A simulated scene (sim.scene.Scene: rig, truth, detections) with its panels, the site of
    their zones, the workers' scripts and their scripted falls."""

    scene: Scene
    kind: str
    site: Site
    panels: tuple[Panel, ...]
    actors: tuple[Actor, ...]
    falls: tuple[Fall, ...]
    down_s: float

    @property
    def duration_s(self) -> float:
        return self.scene.num_frames / self.scene.fps


class ActShape(TypedDict, total=False):
    """An act's shape beyond its kind, times, place and heading (sim.postures.Act)."""

    ease_s: float
    reach: tuple[float, float]
    work: float
    fall_dir: float


class _Script:
    """Builds one worker's acts in time order."""

    def __init__(self, rng: np.random.Generator, start: np.ndarray, heading: float) -> None:
        self.rng, self.t, self.pos, self.heading = rng, 0.0, np.asarray(start, float), heading
        self.acts: list[Act] = []
        self.speed = float(rng.uniform(1.1, 1.4))
        self.last = "stand"

    def add(
        self, kind: str, dur: float, heading: float | None = None, **kw: Unpack[ActShape]
    ) -> None:
        """An act of `dur` seconds where the worker stands, facing `heading` (None: as now)."""
        p = tuple(self.pos)
        heading = self.heading if heading is None else heading
        self.acts.append(Act(kind, self.t, self.t + dur, p, p, heading, **kw))
        self.t += dur
        self.heading, self.last = heading, kind

    def walk(self, target: np.ndarray) -> None:
        if self.last not in ("stand", "walk"):
            self.add("stand", 1.0, ease_s=float(self.rng.uniform(0.8, 1.8)))
        d = np.asarray(target, float) - self.pos
        dist = float(np.hypot(*d))
        if dist < 0.05:
            return
        heading = float(np.arctan2(d[1], d[0]))
        dur = dist / self.speed
        self.acts.append(Act("walk", self.t, self.t + dur, tuple(self.pos), tuple(target), heading))
        self.t += dur
        self.pos, self.heading, self.last = np.asarray(target, float), heading, "walk"

    def turn(self, heading: float) -> None:
        self.add("stand", 0.8, heading=heading, ease_s=0.5)

    def activity(self, kind: str) -> None:
        rng = self.rng
        if kind == "stand":
            self.add("stand", float(rng.uniform(2.0, 8.0)), ease_s=0.6)
        elif kind == "reach":
            reach = ((1.0, 0.0), (0.0, 1.0), (1.0, 1.0))[int(rng.integers(3))]
            self.add("stand", float(rng.uniform(2.0, 6.0)), reach=reach, ease_s=0.8, work=0.05)
        elif kind in ("bend", "stoop"):
            self.add(kind, float(rng.uniform(2.0, 6.0)), ease_s=float(rng.uniform(0.8, 1.5)))
        else:  # squat, kneel, kneel2, sit, sit_floor: sat down or knelt slowly, hands working
            ease = float(rng.uniform(1.5, 3.0) if kind.startswith("sit") else rng.uniform(0.8, 2.0))
            reach = (0.0, 0.0) if kind.startswith("sit") else (0.45, 0.45)
            self.add(kind, float(rng.uniform(4.0, 15.0)), ease_s=ease, reach=reach, work=0.1)

    def fall(self, lie_s: float | None, end_s: float, worker: int) -> Fall:
        rng = self.rng
        dur = float(rng.uniform(0.5, 0.9))
        fall_dir = float(rng.uniform(-np.pi, np.pi))
        # the body twists as it goes down and lands on its front or back, rarely on its side,
        # the arms along the body or stretched out beyond the head
        rel = np.angle(np.exp(1j * (fall_dir - self.heading)))
        heading = fall_dir + (0.0 if abs(rel) < np.pi / 2 else np.pi) + rng.uniform(-0.5, 0.5)
        t0 = self.t
        lie = (end_s - t0 + 5.0) if lie_s is None else dur + lie_s
        self.add(
            "fall",
            lie,
            ease_s=dur,
            fall_dir=fall_dir,
            heading=float(heading),
            reach=(arms := float(rng.random() < 0.4), arms),
        )
        if lie_s is None:
            return Fall(worker, t0, t0 + dur, None)
        # up slowly after a long time down; scrambling up after a stumble
        ease = float(rng.uniform(2.5, 3.5) if lie_s > 2.0 else rng.uniform(1.0, 1.4))
        self.add("get_up", ease + 0.8, ease_s=ease, fall_dir=fall_dir)
        return Fall(worker, t0, t0 + dur, t0 + dur + lie_s)


def _interior(
    rng: np.random.Generator, room: tuple[float, float], margin: float = 1.6
) -> np.ndarray:
    return rng.uniform([margin, margin], [room[0] - margin, room[1] - margin])


def _routine(
    rng: np.random.Generator,
    room: tuple[float, float],
    duration_s: float,
    worker: int,
    fall_at: float | None = None,
    down_s: float = 3.0,
) -> tuple[_Script, list[Fall]]:
    """Acts of a worker moving between activities; with fall_at (s) one fall there or after."""
    s = _Script(rng, _interior(rng, room), float(rng.uniform(-np.pi, np.pi)))
    s.t = -float(rng.uniform(0.0, 3.0))
    falls = []
    while s.t < duration_s:
        upright = s.last in ("walk", "stand", "bend", "stoop")  # "stand" includes reaching
        if fall_at is not None and s.t >= fall_at and not falls and upright:
            u = rng.random()
            if u < 0.5 or duration_s - s.t < down_s + 14.0:
                lie = None
            elif u < 0.75:
                lie = float(rng.uniform(down_s + 3.0, down_s + 8.0))
            else:
                lie = float(rng.uniform(0.2, 0.6))
            falls.append(s.fall(lie, duration_s, worker))
            if lie is None:
                break
            continue
        target = _interior(rng, room)
        for _ in range(10):
            if np.hypot(*(target - s.pos)) >= 1.5:
                break
            target = _interior(rng, room)
        s.walk(target)
        if fall_at is not None and s.t >= fall_at and not falls:
            # a trip while walking: the fall comes straight out of the walk; or a slip, a
            # faint or a shock while standing, reaching up or bent over
            if rng.random() >= 0.6:
                s.activity(UPRIGHT[int(rng.integers(len(UPRIGHT)))])
            continue
        s.activity(ACTIVITIES[int(rng.integers(len(ACTIVITIES)))])
    return s, falls


def _wait(rng: np.random.Generator) -> np.ndarray:
    return rng.uniform(*WAIT)


def _idle(s: _Script, until: float) -> None:
    """Wait in the middle of the room until `until` s: stand a few seconds, step elsewhere."""
    while s.t < until - 1e-6:
        left = until - s.t
        target = _wait(s.rng)
        walk_s = np.hypot(*(target - s.pos)) / s.speed
        if left > 4.0 and s.rng.random() < 0.5 and walk_s + 1.0 < left:
            s.walk(target)
            continue
        turn = float(s.heading + s.rng.uniform(-1.0, 1.0))
        s.add("stand", min(left, float(s.rng.uniform(2.0, 6.0))), heading=turn, ease_s=0.6)


def _work(
    rng: np.random.Generator, panels: Sequence[Panel], duration_s: float, num_people: int
) -> list[_Script]:
    """Scripts of workers doing jobs at the panels one at a time; the others wait."""
    scripts = [
        _Script(rng, _wait(rng), float(rng.uniform(-np.pi, np.pi))) for _ in range(num_people)
    ]
    t = 1.0
    while t < duration_s:
        panel = panels[int(rng.integers(len(panels)))]
        team = rng.permutation(num_people)[: 1 if num_people < 2 or rng.random() < 0.5 else 2]
        glance = len(team) == 1 and rng.random() < 0.25  # a short look, shorter than lone_s
        work_s = float(rng.uniform(2.0, 4.0) if glance else rng.uniform(14.0, 28.0))
        stand = np.asarray(panel.stand)
        side = np.asarray(panel.side)
        u = rng.random()
        facing = np.radians(panel.facing_deg)
        offset = float(rng.choice([-1, 1]))
        if u < 0.2:  # facing away from the panel, hand still in it
            facing += offset * float(rng.uniform(np.radians(55), np.radians(90)))
        elif u < 0.4:  # beside the work area, in front of the panel
            stand = stand + offset * float(rng.uniform(0.6, 0.7)) * side
        else:
            facing += float(rng.uniform(-np.radians(10), np.radians(10)))
        toward = np.radians(panel.facing_deg)
        # the buddy: beside the panel on the other side, a little farther back
        buddy = np.asarray(panel.stand) - offset * 1.15 * side
        places = [stand, buddy - 0.2 * np.array([np.cos(toward), np.sin(toward)])]
        start = max(t, *(scripts[k].t for k in team))
        for k in team:
            _idle(scripts[k], start)
        for i, k in enumerate(team):
            s = scripts[k]
            s.walk(places[i])
            s.turn(float(facing) if i == 0 else toward)
        end = max(scripts[k].t for k in team) + work_s
        for i, k in enumerate(team):
            s = scripts[k]
            if i == 0:  # hands in the panel, standing or kneeling
                kneel = rng.random() < 0.3
                reach = (0.5, 0.5) if kneel else (0.55, 0.55)
                s.add("kneel" if kneel else "stand", end - s.t, reach=reach, work=0.06)
            else:  # watching, hands busy
                s.add("stand", end - s.t, ease_s=0.6, work=0.05)
            s.walk(_wait(rng))
        t = max(scripts[k].t for k in team) + float(rng.uniform(1.0, 4.0))
    for s in scripts:
        _idle(s, duration_s + 1.0)
    return scripts


@dataclass(frozen=True)
class Take:
    """How an acted scene is filmed: fps, its length in frames, the room (width, depth,
    height, metres), and the difficulty and seed it is known by."""

    fps: float
    num_frames: int
    room: tuple[float, float, float]
    difficulty: str
    seed: int


def acted_scene(
    actors: Sequence[Actor],
    rig: Rig,
    noise: DetectorNoise,
    take: Take,
    detect_rng: np.random.Generator,
) -> Scene:
    """The scene of scripted workers: their joints per frame (kept MIN_APART_M apart) and the
    detector's view of them in every camera of `rig`."""
    fps, room = take.fps, take.room
    T, N, floor = take.num_frames, len(actors), room[:2]
    truth = np.full((T, N, NUM_JOINTS, 3), np.nan)
    present = np.zeros((T, N), dtype=bool)
    xy = np.zeros((N, T, 2))
    for n, a in enumerate(actors):
        sig = a.signals(T, fps)
        xy[n] = np.column_stack([sig["x"], sig["y"]])
        present[:, n] = sig["present"]
    xy = keep_apart(xy, present.T, MIN_APART_M, fps, floor)
    for n, a in enumerate(actors):
        truth[:, n], _ = a.track(T, fps, xy[n])
    detections, labels = detect(truth, rig, noise, detect_rng, floor)
    return Scene(
        rig=rig,
        fps=float(fps),
        truth=truth,
        present=present,
        ids=np.arange(1, N + 1, dtype=np.int64),
        detections=detections,
        detection_truth=labels,
        difficulty=take.difficulty,
        seed=int(take.seed),
        room=room,
    )


def simulate_behaviour(
    kind: str = "falls",
    seed: int = 0,
    difficulty: str = "mid",
    duration_s: float = 60.0,
    num_people: int | None = None,
    fps: float = 25.0,
    *,
    num_cameras: int | None = None,
    down_s: float = 3.0,
    noise: DetectorNoise | None = None,
) -> BehaviourScene:
    """A behaviour scene of `kind` ("falls", "routine", "work"); the rig, the cameras' count and
    the detector's errors are those of sim.scene's `difficulty`; num_people: default 3 (falls,
    routine) or 3 (work)."""
    if kind not in SCENE_KINDS:
        raise ValueError(f"unknown scene kind {kind!r}; expected one of {', '.join(SCENE_KINDS)}")
    preset = ScenePreset.preset(difficulty)
    noise = DetectorNoise.preset(difficulty) if noise is None else noise
    C = preset.num_cameras if num_cameras is None else int(num_cameras)
    N = 3 if num_people is None else int(num_people)
    if N < 1 or duration_s <= 0:
        raise ValueError(f"need num_people >= 1 and duration_s > 0, got {N}, {duration_s}")
    room = (12.0, 8.0, 4.0)
    floor = room[:2]
    rig = make_rig(C, np.random.default_rng(seed), room)
    panels = make_panels(np.random.default_rng([seed, 5]), floor)
    T = round(duration_s * fps)
    actors, falls = [], []
    if kind == "work":
        scripts = _work(np.random.default_rng([seed, 6]), panels, duration_s, N)
        script_falls = [[] for _ in scripts]
    else:
        scripts, script_falls = [], []
        for n in range(N):
            wrng = np.random.default_rng([seed, 1, n])
            fall_at = (
                float(wrng.uniform(3.0, max(3.5, duration_s - 20.0))) if kind == "falls" else None
            )
            s, f = _routine(wrng, floor, duration_s, n + 1, fall_at, down_s)
            scripts.append(s)
            script_falls.append(f)
    for n, s in enumerate(scripts):
        wrng = np.random.default_rng([seed, 4, n])
        actors.append(
            Actor(
                height=float(wrng.uniform(1.55, 1.95)),
                step_hz=float(wrng.uniform(1.7, 1.9)),
                phase0=float(wrng.uniform(0.0, 2.0 * np.pi)),
                acts=tuple(s.acts),
                room=floor,
                seed=int(wrng.integers(2**31)),
                falls=tuple(script_falls[n]),
            )
        )
        falls += script_falls[n]
    take = Take(fps, T, room, difficulty, seed)
    scene = acted_scene(actors, rig, noise, take, np.random.default_rng([seed, 2]))
    zones = tuple(z for p in panels for z in (p.energized, p.work_area))
    return BehaviourScene(
        scene=scene,
        kind=kind,
        site=Site(zones, fps),
        panels=panels,
        actors=tuple(actors),
        falls=tuple(falls),
        down_s=down_s,
    )
