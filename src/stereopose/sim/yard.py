"""A simulated substation yard for calibration without a board: cameras on poles 6-9 m high
around a yard of 40 x 25 m (baselines to about 46 m), workers walking through it seen by a
detector with misses, left/right swaps and ghosts, and surveyed points clicked in each view.

World frame: metres, z up, floor at z = 0, the yard spans [0, width] x [0, depth].
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from stereopose.sim.detections import DetectorNoise, detect, project_visible
from stereopose.sim.motion import Worker, keep_apart
from stereopose.sim.scene import IMAGE_SIZE, _distortion_ok, look_at
from stereopose.skeleton import NUM_JOINTS
from stereopose.types import Camera, People2D, Rig

__all__ = ["Yard", "aligned", "bump", "rig_errors", "survey", "yard_rig", "yard_scene"]

YARD = (40.0, 25.0)
# the poles: the four corners and the middle of the long sides, 1 m outside the fence line
POLES = ((-1.0, -1.0), (20.0, -1.0), (41.0, -1.0), (41.0, 26.0), (20.0, 26.0), (-1.0, 26.0))


def yard_rig(
    rng: np.random.Generator, num_cameras: int = 6, yard: tuple[float, float] = YARD
) -> Rig:
    """`num_cameras` (2-6) pole cameras `cam01`.. with 1080p lenses of f 1500-2400 px and mild
    barrel distortion, each looking at a point of the yard's middle part."""
    if not 2 <= num_cameras <= len(POLES):
        raise ValueError(f"num_cameras must be 2..{len(POLES)}, got {num_cameras}")
    W, D = yard
    cams = []
    for k in range(num_cameras):
        px, py = POLES[k]
        centre = np.array([px * W / 40.0, py * D / 25.0, rng.uniform(6.0, 9.0)])
        target = np.array([rng.uniform(0.3, 0.7) * W, rng.uniform(0.3, 0.7) * D, 0.0])
        R = look_at(centre, target)
        fx = rng.uniform(1500.0, 2400.0)
        k1 = k2 = 0.0
        for _ in range(100):
            k1, k2 = rng.uniform(-0.12, -0.02), rng.uniform(0.0, 0.05)
            if _distortion_ok(fx, k1, k2):
                break
        K = np.array(
            [
                [fx, 0.0, IMAGE_SIZE[0] / 2 + rng.uniform(-15, 15)],
                [0.0, fx, IMAGE_SIZE[1] / 2 + rng.uniform(-15, 15)],
                [0.0, 0.0, 1.0],
            ]
        )
        dist = np.array([k1, k2, *rng.uniform(-5e-4, 5e-4, 2)])
        cams.append(Camera(f"cam{k + 1:02d}", IMAGE_SIZE, K, dist, R, -R @ centre))
    return Rig(tuple(cams))


@dataclass(frozen=True, eq=False)
class Yard:
    """rig: the true cameras; truth (T, N, 17, 3) metres (NaN: absent); detections[t][camera]:
    People2D; fps; yard (width, depth); heights (N,) the walkers' standing heights, metres."""

    rig: Rig
    truth: np.ndarray
    detections: list[dict[str, People2D]]
    fps: float
    yard: tuple[float, float]
    heights: tuple[float, ...] = ()


def yard_noise() -> DetectorNoise:
    """A detector like YOLO-Pose on people 150-500 px tall: 1 % of the box jitter, misses,
    swaps and ghosts."""
    return DetectorNoise(
        sigma_frac=0.008,
        outlier_rate=0.01,
        joint_miss=0.01,
        person_miss=0.05,
        swap=0.03,
        leg_swap=0.02,
        ghosts=0.05,
    )


def yard_scene(
    seed: int = 0,
    walkers: int = 1,
    duration_s: float = 120.0,
    fps: float = 25.0,
    *,
    num_cameras: int = 6,
    noise: DetectorNoise | None = None,
    rig: Rig | None = None,
    yard: tuple[float, float] = YARD,
) -> Yard:
    """Workers walking through the yard for `duration_s`, seen by the rig (default: a new one
    from the seed) through the detector model `noise` (default: yard_noise())."""
    rig = rig if rig is not None else yard_rig(np.random.default_rng(seed), num_cameras, yard)
    T = round(duration_s * fps)
    truth = np.full((T, walkers, NUM_JOINTS, 3), np.nan)
    xy = np.zeros((walkers, T, 2))
    present = np.ones((walkers, T), dtype=bool)
    workers = []
    for n in range(walkers):
        w = Worker.random(np.random.default_rng([seed, 5, n]), yard, duration_s)
        workers.append(w)
        s = w.signals(T, fps)
        xy[n] = np.column_stack([s["x"], s["y"]])
        present[n] = s["present"]
    xy = keep_apart(xy, present, 0.5, fps, yard)
    for n, w in enumerate(workers):
        truth[:, n], _ = w.track(T, fps, xy[n])
    dets, _ = detect(truth, rig, noise or yard_noise(), np.random.default_rng([seed, 6]), yard)
    return Yard(
        rig,
        truth,
        dets,
        float(fps),
        (float(yard[0]), float(yard[1])),
        tuple(float(w.height) for w in workers),
    )


def survey(
    rig: Rig,
    rng: np.random.Generator,
    count: int = 12,
    click_px: float = 1.0,
    yard: tuple[float, float] = YARD,
    min_seen: int = 8,
) -> tuple[dict[str, np.ndarray], dict[str, dict[str, np.ndarray]]]:
    """`count` surveyed points (on the ground and on equipment up to 4 m) chosen so that every
    camera sees at least `min_seen` of them, and their clicks (pixels, Gaussian error of
    `click_px`): ({point: (3,)}, {camera: {point: (2,)}})."""
    W, D = yard
    for _ in range(2000):
        pts = np.column_stack(
            [
                rng.uniform(0.15 * W, 0.85 * W, count),
                rng.uniform(0.15 * D, 0.85 * D, count),
                np.where(rng.random(count) < 0.4, 0.0, rng.uniform(0.5, 4.0, count)),
            ]
        )
        seen = [project_visible(pts, cam) for cam in rig]
        if all(ok.sum() >= min_seen for _, ok in seen):
            break
    else:
        raise RuntimeError("no set of surveyed points is seen well enough by every camera")
    world = {f"P{i + 1}": pts[i] for i in range(count)}
    clicks = {
        cam.name: {f"P{i + 1}": uv[i] + rng.normal(0.0, click_px, 2) for i in np.flatnonzero(ok)}
        for cam, (uv, ok) in zip(rig, seen, strict=True)
    }
    return world, clicks


def bump(cam: Camera, rng: np.random.Generator, degrees: float, metres: float) -> Camera:
    """The camera turned by `degrees` about a random axis through its centre and its centre
    moved by `metres` in a random direction (a pole hit, a bracket slipped)."""
    import cv2

    axis = rng.normal(size=3)
    axis *= np.radians(degrees) / np.linalg.norm(axis)
    turn = cv2.Rodrigues(axis)[0]
    shift = rng.normal(size=3)
    shift *= metres / np.linalg.norm(shift)
    R = turn @ cam.R
    centre = cam.center + shift
    return Camera(cam.name, cam.size, cam.matrix, cam.distortions, R, -R @ centre)


def _yaw_fit(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The turn about z (3, 3) and shift (3,) on the floor best taking centres a onto b."""
    ca, cb = a[:, :2].mean(0), b[:, :2].mean(0)
    U, _, Vt = np.linalg.svd((a[:, :2] - ca).T @ (b[:, :2] - cb))
    Z = Vt.T @ U.T
    if np.linalg.det(Z) < 0:
        Z = Vt.T @ np.diag([1.0, -1.0]) @ U.T
    Q = np.eye(3)
    Q[:2, :2] = Z
    return Q, np.append(cb - Z @ ca, 0.0)


def aligned(est: Rig, truth: Rig) -> Rig:
    """`est` turned about z and shifted on the floor onto `truth` (its own yaw and origin
    taken out; its scale, floor and tilt kept)."""
    a = np.stack([est[n].center for n in truth.names])
    b = np.stack([truth[n].center for n in truth.names])
    Q, shift = _yaw_fit(a, b)
    cams = []
    for c in est:
        R = c.R @ Q.T
        cams.append(Camera(c.name, c.size, c.matrix, c.distortions, R, -R @ (Q @ c.center + shift)))
    return Rig(tuple(cams))


def rig_errors(est: Rig, truth: Rig) -> dict:
    """How far a rig in a world frame of its own choosing (z up, floor at z = 0, any yaw and
    origin on the floor) is from the true one: the yaw and floor shift that fit the camera
    centres best are taken out, then per camera its rotation (degrees) and position (metres)
    error; the scale (ratio of the mean baselines), the floor's height (mean z of the centres
    apart) and its tilt (degrees, from the rotations' mean difference)."""
    import cv2

    names = truth.names
    a = np.stack([est[n].center for n in names])
    b = np.stack([truth[n].center for n in names])
    Q, shift = _yaw_fit(a, b)
    moved = a @ Q.T + shift
    rot, pos, ups = {}, {}, []
    for i, n in enumerate(names):
        R = est[n].R @ Q.T  # world(true) -> camera
        diff = R.T @ truth[n].R
        rot[n] = float(np.degrees(np.linalg.norm(cv2.Rodrigues(diff)[0])))
        pos[n] = float(np.linalg.norm(moved[i] - b[i]))
        ups.append(R.T @ truth[n].R @ np.array([0.0, 0.0, 1.0]))
    up = np.mean(ups, axis=0)
    size = float(np.max(np.linalg.norm(b[:, None] - b[None], axis=-1)))
    base = lambda c: np.linalg.norm(c[:, None] - c[None], axis=-1).sum()  # noqa: E731
    return {
        "rotation_deg": rot,
        "position_m": pos,
        "rig_size_m": size,
        "scale": float(base(a) / base(b)),
        "floor_m": float(np.mean(moved[:, 2] - b[:, 2])),
        "tilt_deg": float(np.degrees(np.arccos(np.clip(up[2] / np.linalg.norm(up), -1, 1)))),
    }
