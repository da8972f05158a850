"""Synthetic substation scenes: a camera rig around a room, workers moving in it, ground truth
and simulated 2D detections.

World frame: metres, z up, floor at z = 0, the room spans [0, width] x [0, depth] x [0, height].
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from stereopose.sim.detections import DetectorNoise, detect, joints_in_view, max_ideal_radius
from stereopose.sim.motion import Door, Worker, keep_apart
from stereopose.skeleton import NUM_JOINTS
from stereopose.types import Camera, People2D, People3D, Rig

IMAGE_SIZE = (1920.0, 1080.0)
# Closest two workers' hip centres come: two bodies (0.45 m across the shoulders) cannot
# overlap, and people passing each other leave about this much between them.
MIN_APART_M = 0.5


@dataclass(frozen=True)
class ScenePreset:
    """Scene defaults of one difficulty; probabilities are per worker."""

    num_cameras: int
    num_people: int
    p_enter: float
    p_leave: float

    @classmethod
    def preset(cls, difficulty: str) -> ScenePreset:
        presets = {
            "easy": cls(4, 2, 0.25, 0.25),
            "mid": cls(6, 4, 0.25, 0.25),
            "hard": cls(6, 6, 0.3, 0.3),
        }
        if difficulty not in presets:
            raise ValueError(f"unknown difficulty {difficulty!r}; expected one of easy, mid, hard")
        return presets[difficulty]


def look_at(center: np.ndarray, target: np.ndarray) -> np.ndarray:
    """World -> camera rotation (3, 3), OpenCV axes (x right, y down, z forward), no roll."""
    z = target - center
    z = z / np.linalg.norm(z)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x = x / np.linalg.norm(x)
    y = np.cross(z, x)
    return np.stack([x, y, z])


def _distortion_ok(fx: float, k1: float, k2: float) -> bool:
    """Barrel distortion must keep growing with the radius well past the image corners."""
    rd = np.hypot(IMAGE_SIZE[0], IMAGE_SIZE[1]) / 2.0 / fx + 0.03
    r = np.linspace(0.0, 4.0, 4001)
    r2 = r * r
    mapped = r * (1.0 + k1 * r2 + k2 * r2 * r2)
    slope = 1.0 + 3.0 * k1 * r2 + 5.0 * k2 * r2 * r2
    reach = np.flatnonzero(mapped >= rd)
    if reach.size == 0:
        return False
    return bool(np.all(slope[r <= 1.25 * r[reach[0]]] > 0.2))


def _perimeter_point(s: float, W: float, D: float, inset: float) -> np.ndarray:
    s = s % (2.0 * (W + D))
    if s < W:
        return np.array([s, inset])
    if s < W + D:
        return np.array([W - inset, s - W])
    if s < 2 * W + D:
        return np.array([2 * W + D - s, D - inset])
    return np.array([inset, 2 * (W + D) - s])


def make_rig(
    num_cameras: int, rng: np.random.Generator, room: tuple[float, float, float] = (12.0, 8.0, 4.0)
) -> Rig:
    """Cameras `cam01`.. near the ceiling around the walls, each looking at the room centre.

    room: (width, depth, height) in metres. Images are 1920 x 1080 with realistic intrinsics
    and barrel distortion. Raises ValueError outside 2..12 cameras.
    """
    if not 2 <= num_cameras <= 12:
        raise ValueError(f"num_cameras must be between 2 and 12, got {num_cameras}")
    W, D, H = (float(v) for v in room)
    per = 2.0 * (W + D)
    offset = rng.uniform(0.0, per)
    cams = []
    for k in range(num_cameras):
        s = offset + (k + rng.uniform(-0.15, 0.15)) * per / num_cameras
        xy = _perimeter_point(s, W, D, 0.25)
        xy = np.clip(xy, 0.25, [W - 0.25, D - 0.25])
        center = np.array([xy[0], xy[1], rng.uniform(3.0, min(3.8, H - 0.1))])
        target = np.array(
            [
                W / 2 + rng.uniform(-0.12, 0.12) * W,
                D / 2 + rng.uniform(-0.12, 0.12) * D,
                rng.uniform(0.8, 1.2),
            ]
        )
        R = look_at(center, target)
        fx = rng.uniform(750.0, 1100.0)  # 2.8-4 mm surveillance lenses: 82-104 deg wide
        for _ in range(100):
            k1, k2 = rng.uniform(-0.25, -0.05), rng.uniform(0.0, 0.1)
            if _distortion_ok(fx, k1, k2):
                break
        else:
            k1, k2 = -0.05, 0.05
        K = np.array(
            [
                [fx, 0.0, IMAGE_SIZE[0] / 2 + rng.uniform(-20, 20)],
                [0.0, fx, IMAGE_SIZE[1] / 2 + rng.uniform(-20, 20)],
                [0.0, 0.0, 1.0],
            ]
        )
        dist = np.array([k1, k2, *rng.uniform(-1e-3, 1e-3, 2)])
        cam = Camera(f"cam{k + 1:02d}", IMAGE_SIZE, K, dist, R, -R @ center)
        if max_ideal_radius(cam) <= 0:
            raise RuntimeError(f"{cam.name}: degenerate distortion {dist.tolist()}")
        cams.append(cam)
    rig = Rig(tuple(cams))
    floor_centre = np.array([[W / 2, D / 2, 0.0]])
    if not joints_in_view(floor_centre[None], rig).all():
        raise RuntimeError("a simulated camera does not see the room's floor centre")
    return rig


def make_doors(
    rng: np.random.Generator, room: tuple[float, float], count: int = 2
) -> tuple[Door, ...]:
    """`count` doors on random walls: (point on the wall, inward unit normal)."""
    W, D = room
    walls = rng.permutation(4)[:count]
    doors = []
    for w in walls:
        if w in (0, 2):
            x = rng.uniform(1.0, W - 1.0)
            doors.append(
                (np.array([x, 0.0 if w == 0 else D]), np.array([0.0, 1.0 if w == 0 else -1.0]))
            )
        else:
            y = rng.uniform(1.0, D - 1.0)
            doors.append(
                (np.array([W if w == 1 else 0.0, y]), np.array([-1.0 if w == 1 else 1.0, 0.0]))
            )
    return tuple(doors)


@dataclass(frozen=True, eq=False)
class Scene:
    """A simulated scene with its ground truth.

    truth: (T, N, 17, 3) metres, NaN where worker n is absent; present: (T, N) bool; ids: (N,)
    worker ids; detections[t][camera name]: People2D in pixels of the distorted image;
    detection_truth[t][camera name]: (P,) index n of the worker behind each detection, -1 for a
    false detection. room: (width, depth, height) in metres.
    """

    rig: Rig
    fps: float
    truth: np.ndarray
    present: np.ndarray
    ids: np.ndarray
    detections: list[dict[str, People2D]]
    detection_truth: list[dict[str, np.ndarray]]
    difficulty: str
    seed: int
    room: tuple[float, float, float] = (12.0, 8.0, 4.0)
    workers: tuple[Worker, ...] = ()

    @property
    def num_frames(self) -> int:
        return int(self.truth.shape[0])


def simulate(
    num_cameras: int | None = None,
    num_people: int | None = None,
    num_frames: int = 100,
    seed: int = 0,
    difficulty: str = "mid",
    fps: float = 25.0,
    *,
    p_enter: float | None = None,
    p_leave: float | None = None,
    noise: DetectorNoise | None = None,
    room: tuple[float, float, float] = (12.0, 8.0, 4.0),
) -> Scene:
    """A random scene; None takes the default of `difficulty` ("easy", "mid", "hard").

    p_enter / p_leave: probability that a worker starts outside and walks in, or walks out
    before the end. The rig comes from `np.random.default_rng(seed)`; the workers and the
    detections from independent streams of the same seed, so the motion does not depend on the
    number of cameras.
    """
    preset = ScenePreset.preset(difficulty)
    noise = DetectorNoise.preset(difficulty) if noise is None else noise
    C = preset.num_cameras if num_cameras is None else int(num_cameras)
    N = preset.num_people if num_people is None else int(num_people)
    p_enter = preset.p_enter if p_enter is None else p_enter
    p_leave = preset.p_leave if p_leave is None else p_leave
    if num_frames < 1 or N < 0:
        raise ValueError(f"need num_frames >= 1 and num_people >= 0, got {num_frames}, {N}")
    rig = make_rig(C, np.random.default_rng(seed), room)
    floor = (float(room[0]), float(room[1]))
    doors = make_doors(np.random.default_rng([seed, 3]), floor)
    duration = num_frames / fps
    workers = []
    truth = np.full((num_frames, N, NUM_JOINTS, 3), np.nan)
    present = np.zeros((num_frames, N), dtype=bool)
    xy = np.zeros((N, num_frames, 2))
    for n in range(N):
        wrng = np.random.default_rng([seed, 1, n])
        enters, leaves = wrng.random() < p_enter, wrng.random() < p_leave
        w = Worker.random(wrng, floor, duration, enters=enters, leaves=leaves, doors=doors)
        workers.append(w)
        s = w.signals(num_frames, fps)
        xy[n] = np.column_stack([s["x"], s["y"]])
        present[:, n] = s["present"]
    # plans are drawn one worker at a time; bodies cannot overlap, so the workers give way
    xy = keep_apart(xy, present.T, MIN_APART_M, fps, floor)
    for n, w in enumerate(workers):
        truth[:, n], _ = w.track(num_frames, fps, xy[n])
    detections, labels = detect(truth, rig, noise, np.random.default_rng([seed, 2]), floor)
    return Scene(
        rig=rig,
        fps=float(fps),
        truth=truth,
        present=present,
        ids=np.arange(1, N + 1, dtype=np.int64),
        detections=detections,
        detection_truth=labels,
        difficulty=difficulty,
        seed=int(seed),
        room=(float(room[0]), float(room[1]), float(room[2])),
        workers=tuple(workers),
    )


def truth_people3d(scene: Scene, t: int) -> People3D:
    """The workers present at frame t as People3D: ids = worker ids, conf 1, views = number of
    cameras whose image holds the joint, no detections (-1)."""
    idx = np.flatnonzero(scene.present[t])
    joints = scene.truth[t, idx]
    P, C = idx.shape[0], len(scene.rig)
    views = joints_in_view(joints[None], scene.rig)[0].sum(0) if P else np.zeros((0, NUM_JOINTS))
    return People3D(
        frame=t,
        joints=joints,
        conf=np.ones((P, NUM_JOINTS)),
        ids=scene.ids[idx],
        reprojection_px=np.zeros((P, NUM_JOINTS)),
        views=views,
        detections=np.full((P, C), -1, dtype=np.int64),
    )


def ghost_frame(scene: Scene, t: int, where: tuple[float, float]) -> list[People2D]:
    """Frame t's detections in rig order plus a false person standing at floor point `where`,
    consistent in every camera (the pose of the first worker present, moved there)."""
    from stereopose.geometry.camera import project

    n = int(np.flatnonzero(scene.present[t])[0])
    body = scene.truth[t, n].copy()
    body[:, :2] += np.asarray(where, dtype=np.float64) - np.nanmean(body[:, :2], axis=0)
    out = []
    for cam in scene.rig:
        kp = np.concatenate([project(body, cam), np.full((NUM_JOINTS, 1), 0.9)], axis=-1)
        old = scene.detections[t][cam.name]
        out.append(People2D(cam.name, t, np.concatenate([old.keypoints, kp[None]])))
    return out
