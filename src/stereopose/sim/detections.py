"""2D detections with detector-like errors, made from the true 3D joints and the rig.

Errors modelled: pixel noise proportional to the person's image size, heavy-tailed outliers,
occlusion by nearer people, missed joints and people, left/right swaps (more often seen from the
back), false detections ("ghosts") and a shuffled order of people.
"""

from __future__ import annotations

import functools
import warnings
from dataclasses import dataclass

import numpy as np

from stereopose.geometry.camera import distort, normalized_to_pixels, world_to_camera
from stereopose.sim.motion import pose
from stereopose.skeleton import LEFT_SHOULDER, NUM_JOINTS, RIGHT_SHOULDER, SWAP
from stereopose.types import Camera, People2D, Rig

FACE = np.arange(5)
LEG_SWAP = np.arange(NUM_JOINTS)
LEG_SWAP[13:17] = SWAP[13:17]  # knees and ankles only


@dataclass(frozen=True)
class DetectorNoise:
    """Error model of the simulated 2D detector.

    Sizes (`*_frac`) are fractions of the person's bounding-box height in the image; rates are
    probabilities per joint (`outlier_rate`, `joint_miss`) or per person, camera and frame
    (`person_miss`, `swap`, `leg_swap`); `ghosts` is the mean number of false detections per
    camera and frame. A full left/right swap has probability `swap` when the person faces the
    camera and `back_swap_factor * swap` when its back does.
    """

    sigma_frac: float = 0.01
    outlier_rate: float = 0.01
    outlier_frac: tuple[float, float] = (0.10, 0.30)
    outlier_conf: tuple[float, float] = (0.1, 0.35)
    occluded_visible: float = 1.0  # pose detectors report all 17 joints, occluded ones weakly
    occluded_frac: tuple[float, float] = (0.02, 0.08)
    occluded_conf: tuple[float, float] = (0.05, 0.4)
    occluder_shrink: float = 0.1
    visible_conf: tuple[float, float] = (0.6, 0.98)
    face_away_factor: tuple[float, float] = (0.5, 0.8)
    joint_miss: float = 0.01
    person_miss: float = 0.05
    swap: float = 0.05
    back_swap_factor: float = 2.0
    leg_swap: float = 0.02
    ghosts: float = 0.05
    ghost_conf: tuple[float, float] = (0.3, 0.8)
    min_joints: int = 5

    @classmethod
    def exact(cls) -> DetectorNoise:
        """A detector without noise, outliers, misses, swaps or ghosts (occluded joints still
        get their low confidence and error)."""
        return cls(
            sigma_frac=0.0,
            outlier_rate=0.0,
            joint_miss=0.0,
            person_miss=0.0,
            swap=0.0,
            leg_swap=0.0,
            ghosts=0.0,
        )

    @classmethod
    def preset(cls, difficulty: str) -> DetectorNoise:
        """The error model of `difficulty`: "easy", "mid" or "hard"."""
        presets = {
            "easy": cls(
                sigma_frac=0.006,
                outlier_rate=0.005,
                joint_miss=0.005,
                person_miss=0.02,
                swap=0.0,
                leg_swap=0.0,
                ghosts=0.0,
            ),
            "mid": cls(),
            "hard": cls(
                sigma_frac=0.015,
                outlier_rate=0.03,
                joint_miss=0.02,
                person_miss=0.10,
                swap=0.15,
                leg_swap=0.05,
                ghosts=0.15,
            ),
        }
        if difficulty not in presets:
            raise ValueError(f"unknown difficulty {difficulty!r}; expected one of easy, mid, hard")
        return presets[difficulty]


def max_ideal_radius(camera: Camera) -> float:
    """Largest ideal normalised radius that lands inside the image (up to its corners).

    Beyond it, barrel distortion can fold far-off points back into the image; such points are
    not visible.
    """
    K, d = camera.matrix, camera.distortions
    k3 = float(d[4]) if d.shape[0] > 4 else 0.0
    focal_centre = (float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2]))
    return _max_ideal_radius(focal_centre, tuple(camera.size), (float(d[0]), float(d[1]), k3))


@functools.lru_cache(maxsize=256)
def _max_ideal_radius(
    focal_centre: tuple[float, float, float, float],
    size: tuple[float, float],
    radial: tuple[float, float, float],
) -> float:
    """(fx, fy, cx, cy), the image's (w, h) and its radial distortion (k1, k2, k3)."""
    fx, fy, cx, cy = focal_centre
    (w, h), (k1, k2, k3) = size, radial
    corners = np.array([[0.0, 0.0], [w, 0.0], [0.0, h], [w, h]])
    x = (corners[:, 0] - cx) / fx
    y = (corners[:, 1] - cy) / fy
    rd = float(np.hypot(x, y).max())
    r = np.linspace(0.0, 4.0, 4001)
    r2 = r * r
    mapped = r * (1.0 + r2 * (k1 + r2 * (k2 + r2 * k3)))
    beyond = np.flatnonzero(mapped >= rd)
    if beyond.size == 0:
        return float(r[np.argmax(mapped)])
    # stop where the mapping stops growing, if that comes first
    grow = np.flatnonzero(np.diff(mapped) <= 0)
    limit = r[beyond[0]] if grow.size == 0 else min(r[beyond[0]], r[grow[0]])
    return float(limit) * 1.05


def project_visible(
    points_world: np.ndarray, camera: Camera, r_max: float | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Distorted pixels (..., 2) of world points (..., 3) and whether each is in the image (...,).

    A point is visible when it is in front of the camera (> 0.1 m), within `r_max` (ideal
    normalised radius, default `max_ideal_radius(camera)`) and inside the image.
    """
    if r_max is None:
        r_max = max_ideal_radius(camera)
    Xc = world_to_camera(points_world, camera)
    z = Xc[..., 2]
    front = z > 0.1
    with np.errstate(invalid="ignore", divide="ignore"):
        xy = np.where(front[..., None], Xc[..., :2] / z[..., None], np.nan)
    uv = normalized_to_pixels(distort(xy, camera.distortions), camera.matrix)
    w, h = camera.size
    with np.errstate(invalid="ignore"):
        ok = (
            front
            & (np.hypot(xy[..., 0], xy[..., 1]) <= r_max)
            & (uv[..., 0] >= 0)
            & (uv[..., 0] < w)
            & (uv[..., 1] >= 0)
            & (uv[..., 1] < h)
        )
    return uv, ok


def joints_in_view(truth: np.ndarray, rig: Rig) -> np.ndarray:
    """(T, C, N, 17) bool: true joint (T, N, 17, 3) falls inside camera c's image."""
    return np.stack([project_visible(truth, cam)[1] for cam in rig], axis=1)


def _random_shift(rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
    a = rng.uniform(0.0, 2.0 * np.pi, shape)
    return np.stack([np.cos(a), np.sin(a)], axis=-1)


def _boxes(kp: np.ndarray, size: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
    """(P, 4) keypoint boxes padded by 5 % and (P,) mean confidence of the reported joints."""
    ok = kp[..., 2] > 0
    x = np.where(ok, kp[..., 0], np.nan)
    y = np.where(ok, kp[..., 1], np.nan)
    with warnings.catch_warnings(), np.errstate(all="ignore"):
        warnings.simplefilter("ignore", RuntimeWarning)
        x1, x2 = np.nanmin(x, axis=1), np.nanmax(x, axis=1)
        y1, y2 = np.nanmin(y, axis=1), np.nanmax(y, axis=1)
        px, py = 0.05 * (x2 - x1), 0.05 * (y2 - y1)
        boxes = np.column_stack([x1 - px, y1 - py, x2 + px, y2 + py])
        scores = np.nanmean(np.where(ok, kp[..., 2], np.nan), axis=1)
    boxes = np.clip(boxes, 0.0, [size[0], size[1], size[0], size[1]])
    return boxes, scores


def _true_boxes(uv: np.ndarray, ok: np.ndarray) -> np.ndarray:
    """(..., 4) boxes of the in-image true joints; NaN when none."""
    x = np.where(ok, uv[..., 0], np.nan)
    y = np.where(ok, uv[..., 1], np.nan)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN rows give NaN, as wanted
        return np.stack(
            [np.nanmin(x, -1), np.nanmin(y, -1), np.nanmax(x, -1), np.nanmax(y, -1)], -1
        )


def _ghosts(
    rng: np.random.Generator, rig: Rig, noise: DetectorNoise, T: int, room: tuple[float, float]
) -> dict[tuple[int, int], np.ndarray]:
    """False detections: standing people at random places, seen by one camera only."""
    counts = (
        rng.poisson(noise.ghosts, (T, len(rig)))
        if noise.ghosts > 0
        else np.zeros((T, 0), dtype=np.int64)
    )
    out: dict[tuple[int, int], np.ndarray] = {}
    if counts.sum() == 0:
        return out
    tt, cc = np.nonzero(counts)
    reps = counts[tt, cc]
    tt, cc = np.repeat(tt, reps), np.repeat(cc, reps)
    G = tt.shape[0]
    conf = rng.uniform(*noise.ghost_conf, (G, NUM_JOINTS))
    jitter = rng.normal(size=(G, NUM_JOINTS, 2))
    for c, cam in enumerate(rig):
        sel = np.flatnonzero(cc == c)
        uv = np.empty((sel.size, NUM_JOINTS, 2))
        ok = np.zeros((sel.size, NUM_JOINTS), dtype=bool)
        # redraw the places that this camera hardly sees, so the rate stays near the mean
        todo = np.arange(sel.size)
        for _ in range(5):
            if todo.size == 0:
                break
            n = todo.size
            xy = rng.uniform([0.0, 0.0], [room[0], room[1]], (n, 2))
            skel = pose(rng.uniform(1.55, 1.95, n), xy, rng.uniform(-np.pi, np.pi, n))
            uv[todo], ok[todo] = project_visible(skel, cam)
            todo = todo[ok[todo].sum(-1) < max(noise.min_joints, 12)]
        box = _true_boxes(uv, ok)
        scale = np.maximum(box[:, 3] - box[:, 1], 10.0)
        uv = uv + jitter[sel] * (noise.sigma_frac * scale)[:, None, None]
        kp = np.concatenate([uv, conf[sel][..., None]], axis=-1)
        kp[~ok] = (np.nan, np.nan, 0.0)
        for g, i in enumerate(sel):
            if ok[g].sum() >= noise.min_joints:
                key = (int(tt[i]), c)
                prev = out.get(key)
                out[key] = kp[g : g + 1] if prev is None else np.concatenate([prev, kp[g : g + 1]])
    return out


def _visibility(
    truth: np.ndarray, rig: Rig, noise: DetectorNoise
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """What each camera sees of the true joints (T, N, 17, 3): pixels uv (T, C, N, 17, 2),
    joints in the image ok (T, C, N, 17), whether the camera sees the person's back
    (T, C, N), joints occluded by a nearer person occ (T, C, N, 17), and each person's scale in
    the image (T, C, N, 1) pixels (the box height)."""
    T, N = truth.shape[:2]
    C = len(rig)
    uv = np.empty((T, C, N, NUM_JOINTS, 2))
    ok = np.empty((T, C, N, NUM_JOINTS), dtype=bool)
    depth = np.empty((T, C, N))
    back = np.empty((T, C, N), dtype=bool)
    # the direction a person faces, from the shoulder line (left shoulder is on its left)
    lr = truth[:, :, LEFT_SHOULDER] - truth[:, :, RIGHT_SHOULDER]
    facing = np.stack([lr[..., 1], -lr[..., 0], np.zeros_like(lr[..., 0])], axis=-1)
    mid = 0.5 * (truth[:, :, LEFT_SHOULDER] + truth[:, :, RIGHT_SHOULDER])
    for c, cam in enumerate(rig):
        uv[:, c], ok[:, c] = project_visible(truth, cam)
        with np.errstate(invalid="ignore"):
            zc = world_to_camera(mid, cam)[..., 2]
            depth[:, c] = np.where(np.isfinite(zc), zc, np.inf)
            back[:, c] = np.sum(facing * (cam.center - mid), axis=-1) < 0
    box = _true_boxes(uv, ok)
    bw, bh = box[..., 2] - box[..., 0], box[..., 3] - box[..., 1]
    scale = np.where(np.isfinite(bh), np.maximum(bh, 10.0), 10.0)[..., None]  # (T, C, N, 1)
    seen = ok.sum(-1) >= noise.min_joints

    # occlusion: joints of a farther person inside the (shrunk) box of a nearer one
    occ = np.zeros_like(ok)
    s = noise.occluder_shrink
    x1, x2 = box[..., 0] + s * bw, box[..., 2] - s * bw
    y1, y2 = box[..., 1] + s * bh, box[..., 3] - s * bh
    for i in range(N):
        for j in range(N):
            if i == j:
                continue
            nearer = seen[..., i] & (depth[..., i] < depth[..., j])
            with np.errstate(invalid="ignore"):
                inside = (
                    (uv[..., j, :, 0] >= x1[..., i, None])
                    & (uv[..., j, :, 0] <= x2[..., i, None])
                    & (uv[..., j, :, 1] >= y1[..., i, None])
                    & (uv[..., j, :, 1] <= y2[..., i, None])
                )
            occ[..., j, :] |= nearer[..., None] & inside & ok[..., j, :]

    return uv, ok, back, occ, scale


def _frames(
    kp: np.ndarray,
    detected: np.ndarray,
    ghosts: dict[tuple[int, int], np.ndarray],
    rig: Rig,
    rng: np.random.Generator,
) -> tuple[list[dict[str, People2D]], list[dict[str, np.ndarray]]]:
    """Per frame and camera the detected people (kp (T, C, N, 17, 3) where detected
    (T, C, N)) with the ghosts added, in a random order, clipped to the image; and the true
    worker behind each (-1: a ghost)."""
    T = kp.shape[0]
    detections: list[dict[str, People2D]] = []
    labels: list[dict[str, np.ndarray]] = []
    for t in range(T):
        frame_d: dict[str, People2D] = {}
        frame_l: dict[str, np.ndarray] = {}
        for c, cam in enumerate(rig):
            idx = np.flatnonzero(detected[t, c])
            people, who = kp[t, c, idx], idx
            g = ghosts.get((t, c))
            if g is not None:
                people = np.concatenate([people, g])
                who = np.concatenate([idx, np.full(g.shape[0], -1)])
            order = rng.permutation(people.shape[0])
            people, who = people[order], who[order].astype(np.int64)
            w, h = cam.size
            people[..., 0] = np.clip(people[..., 0], 0.0, w - 1.0)
            people[..., 1] = np.clip(people[..., 1], 0.0, h - 1.0)
            boxes, scores = _boxes(people, cam.size)
            frame_d[cam.name] = People2D(cam.name, t, people, boxes, scores)
            frame_l[cam.name] = who
        detections.append(frame_d)
        labels.append(frame_l)
    return detections, labels


def detect(
    truth: np.ndarray,
    rig: Rig,
    noise: DetectorNoise,
    rng: np.random.Generator,
    room: tuple[float, float] = (12.0, 8.0),
) -> tuple[list[dict[str, People2D]], list[dict[str, np.ndarray]]]:
    """Simulated detector output for every frame and camera.

    truth: (T, N, 17, 3) true joints in metres, NaN where the worker is absent. Returns, per
    frame, camera name -> People2D (pixels of the distorted image) and camera name -> (P,) index
    of the true worker behind each detection (-1 for a false detection).
    """
    T, N, C = truth.shape[0], truth.shape[1], len(rig)
    uv, ok, back, occ, scale = _visibility(truth, rig, noise)
    shape = ok.shape
    xy = uv + rng.normal(size=(*shape, 2)) * (noise.sigma_frac * scale)[..., None]
    conf = rng.uniform(*noise.visible_conf, shape)
    face_away = rng.uniform(*noise.face_away_factor, shape)
    conf[..., FACE] = np.where(back[..., None], conf * face_away, conf)[..., FACE]
    outlier = rng.random(shape) < noise.outlier_rate
    out_shift = (
        _random_shift(rng, shape) * (rng.uniform(*noise.outlier_frac, shape) * scale)[..., None]
    )
    xy = np.where(outlier[..., None], uv + out_shift, xy)
    conf = np.where(outlier, rng.uniform(*noise.outlier_conf, shape), conf)
    occ_keep = rng.random(shape) < noise.occluded_visible
    occ_shift = (
        _random_shift(rng, shape) * (rng.uniform(*noise.occluded_frac, shape) * scale)[..., None]
    )
    xy = np.where((occ & occ_keep)[..., None], uv + occ_shift, xy)
    conf = np.where(occ & occ_keep, rng.uniform(*noise.occluded_conf, shape), conf)
    valid = ok & ~(occ & ~occ_keep) & ~(rng.random(shape) < noise.joint_miss)
    kp = np.concatenate([xy, conf[..., None]], axis=-1)
    kp[~valid] = (np.nan, np.nan, 0.0)

    u = rng.random((T, C, N))
    p_full = noise.swap * np.where(back, noise.back_swap_factor, 1.0)
    full = u < p_full
    legs = ~full & (u < p_full + noise.leg_swap)
    kp = np.where(full[..., None, None], kp[..., SWAP, :], kp)
    kp = np.where(legs[..., None, None], kp[..., LEG_SWAP, :], kp)
    detected = (valid.sum(-1) >= noise.min_joints) & ~(rng.random((T, C, N)) < noise.person_miss)

    ghosts = _ghosts(rng, rig, noise, T, room)
    return _frames(kp, detected, ghosts, rig, rng)
