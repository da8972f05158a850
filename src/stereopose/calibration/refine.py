"""A camera placed again from the people the other cameras see: a bumped camera, a new one.

The other cameras (kept where they are, two at least) reconstruct each frame's people; every
pairing of such a person with a detection of the camera gives candidate 2D-3D joints, and one
robust PnP (RANSAC) finds the pose most of them agree with, starting from none (a camera
turned by degrees or a new camera is found as well as a nudged one); the pairings that agree
then refine it. The same step corrects a drifted camera while `serve` runs.
"""

from __future__ import annotations

import logging
import math
import warnings
from collections.abc import Iterable
from dataclasses import dataclass

import cv2
import numpy as np

from stereopose.calibration.poses import camera_with_pose, pose_change, robust_pnp
from stereopose.errors import CalibrationError
from stereopose.reconstruction.reconstructor import Reconstructor
from stereopose.types import Camera, People2D, Rig

__all__ = ["Refined", "joints_of_others", "refine_camera", "refine_rig"]

logger = logging.getLogger(__name__)

MIN_CONF = 0.3
MIN_JOINTS = 60  # agreeing joints to accept a pose
RANSAC_PX = 8.0


@dataclass
class Refined:
    """The camera's new pose, its RMS error (px) over the joints that agree, how many agree,
    in how many frames, the share of its view (cells of a 4 x 3 grid) they cover, and how far
    it moved (degrees, metres)."""

    camera: Camera
    rms_px: float
    joints: int
    frames: int
    coverage: float
    turned_deg: float
    moved_m: float


def joints_of_others(
    rig: Rig, camera: str, frames: Iterable[tuple[int, dict[str, People2D]]]
) -> list[tuple[np.ndarray, np.ndarray]]:
    """Per frame, the people the other cameras reconstruct (P, 17, 3) and the camera's own
    detections (D, 17, 3), where both have someone."""
    others = rig.subset([n for n in rig.names if n != camera])
    if len(others) < 2:
        raise CalibrationError(
            f"camera {camera}: at least 2 other calibrated cameras are needed to place it "
            f"(the rig has {', '.join(rig.names)})"
        )
    rec = Reconstructor(others)
    out = []
    for n, people in frames:
        own = people.get(camera)
        if own is None or not len(own.keypoints):
            continue
        p3 = rec(n, {k: v for k, v in people.items() if k != camera})
        if len(p3.joints):
            out.append((p3.joints, own.keypoints))
    return out


def refine_camera(cam: Camera, pairs: list[tuple[np.ndarray, np.ndarray]]) -> Refined:
    """The camera's pose from (people in 3D, its detections) per frame (joints_of_others);
    CalibrationError when too few joints agree."""
    obj, img, tag = _pairings(pairs)
    if not len(obj):
        raise CalibrationError(
            f"camera {cam.name}: no person seen by it and by two other cameras at once"
        )
    best = None
    # from its old pose first (a nudged camera); a pose found from scratch replaces it only
    # when clearly more joints agree (people near the cameras have mirror-like poses too)
    for start, favour in ((_from_old_pose(cam, pairs), 1.0), (_from_scratch(cam, obj, img), 1.3)):
        if start is None:
            continue
        r, t, keep, err = _settle(cam, obj, img, *start)
        if best is None or len(keep) > favour * len(best[2]):
            best = (r, t, keep, err)
    if best is None or len(best[2]) < MIN_JOINTS:
        raise CalibrationError(
            f"camera {cam.name}: {0 if best is None else len(best[2])} joints of the people "
            f"the other cameras see agree on one pose; at least {MIN_JOINTS} are needed (walk "
            "where it and two other cameras see)"
        )
    r, t, keep, err = best
    new = camera_with_pose(cam, np.concatenate([r.ravel(), t.ravel()]))
    w, h = cam.size
    cells = {(int(u / w * 4), int(v / h * 3)) for u, v in img[keep] if 0 <= u < w and 0 <= v < h}
    turned, moved = pose_change(cam, new)
    return Refined(
        new,
        float(np.sqrt(np.mean(err[keep] ** 2))),
        len(keep),
        len(set(tag[keep].tolist())),
        len(cells) / 12.0,
        turned,
        moved,
    )


def pose_error(cam: Camera, pairs: list[tuple[np.ndarray, np.ndarray]]) -> tuple[float, int]:
    """The camera's pose as it is, measured as refine_camera measures its result: the RMS
    error (px) over the joints that agree with it, and how many agree ((inf, 0): none)."""
    obj, img, _ = _pairings(pairs)
    if not len(obj):
        return math.inf, 0
    uv = cv2.projectPoints(obj, cam.rotation, cam.translation, cam.matrix, cam.distortions)[0]
    err = np.linalg.norm(uv.reshape(-1, 2) - img, axis=1)
    keep = np.flatnonzero(err < RANSAC_PX)
    for _ in range(2):
        if len(keep) < 6:
            break
        keep = np.flatnonzero(err < max(3.0, 3.0 * float(np.median(err[keep]))))
    if not len(keep):
        return math.inf, 0
    return float(np.sqrt(np.mean(err[keep] ** 2))), len(keep)


def _pairings(
    pairs: list[tuple[np.ndarray, np.ndarray]],
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every (person, detection) of every frame sharing 6 joints or more: their 3D joints
    (N, 3), the detections' pixels (N, 2) and each joint's frame (N,)."""
    obj, img, tag = [], [], []
    for f, (X, D) in enumerate(pairs):
        for p in range(len(X)):
            for d in range(len(D)):
                ok = np.isfinite(X[p, :, 0]) & (D[d, :, 2] >= MIN_CONF)
                if ok.sum() >= 6:
                    obj.append(X[p, ok])
                    img.append(D[d, ok, :2])
                    tag.append(np.full(int(ok.sum()), f))
    if not obj:
        return np.zeros((0, 3)), np.zeros((0, 2)), np.zeros(0, int)
    return np.concatenate(obj), np.concatenate(img), np.concatenate(tag)


def _from_scratch(
    cam: Camera, obj: np.ndarray, img: np.ndarray
) -> tuple[np.ndarray, np.ndarray] | None:
    """(rvec, tvec) from every pairing's joints by RANSAC, or None."""
    found = robust_pnp(obj, img, cam.matrix, cam.distortions, RANSAC_PX, 10_000)
    return None if found is None or len(found[2]) < 6 else found[:2]


def _from_old_pose(
    cam: Camera, pairs: list[tuple[np.ndarray, np.ndarray]]
) -> tuple[np.ndarray, np.ndarray] | None:
    """(rvec, tvec) refined from the camera's old pose, each detection paired with the
    person it lies nearest to as seen from there (a nudged camera), or None."""
    r = cam.rotation.reshape(3, 1).copy()
    t = cam.translation.reshape(3, 1).copy()
    obj, img = [], []
    for X, D in pairs:
        uv = cv2.projectPoints(np.nan_to_num(X.reshape(-1, 3)), r, t, cam.matrix, cam.distortions)[
            0
        ]
        uv = uv.reshape(len(X), 17, 2)
        for d in range(len(D)):
            ok = np.isfinite(X[..., 0]) & (D[d, :, 2] >= MIN_CONF)[None]
            e = np.where(ok, np.linalg.norm(uv - D[d, None, :, :2], axis=-1), np.nan)
            with warnings.catch_warnings():  # a person with no joint shared: NaN, skipped
                warnings.simplefilter("ignore", RuntimeWarning)
                med = np.nanmedian(np.where(ok.sum(1, keepdims=True) >= 6, e, np.nan), axis=1)
            if not np.isfinite(med).any():
                continue
            p = int(np.nanargmin(med))
            obj.append(X[p, ok[p]])
            img.append(D[d, ok[p], :2])
    if not obj:
        return None
    obj, img = np.concatenate(obj), np.concatenate(img)
    gate = 0.1 * max(cam.size)  # a turn of a few degrees
    for _ in range(4):
        uv = cv2.projectPoints(obj, r, t, cam.matrix, cam.distortions)[0].reshape(-1, 2)
        near = np.linalg.norm(uv - img, axis=1) < gate
        if near.sum() < 6:
            return None
        r, t = cv2.solvePnPRefineLM(obj[near], img[near], cam.matrix, cam.distortions, r, t)
        gate /= 2.0
    return r, t


def _settle(
    cam: Camera, obj: np.ndarray, img: np.ndarray, r: np.ndarray, t: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The pose refined on the joints that agree with it: (rvec, tvec, kept, errors)."""
    uv = cv2.projectPoints(obj, r, t, cam.matrix, cam.distortions)[0].reshape(-1, 2)
    err = np.linalg.norm(uv - img, axis=1)
    keep = np.flatnonzero(err < RANSAC_PX)
    for _ in range(2):
        if len(keep) < 6:
            break
        r, t = cv2.solvePnPRefineLM(obj[keep], img[keep], cam.matrix, cam.distortions, r, t)
        uv = cv2.projectPoints(obj, r, t, cam.matrix, cam.distortions)[0].reshape(-1, 2)
        err = np.linalg.norm(uv - img, axis=1)
        keep = np.flatnonzero(err < max(3.0, 3.0 * float(np.median(err[keep]))))
    return r, t, keep, err


def refine_rig(
    rig: Rig, cameras: list[str], frames: list[tuple[int, dict[str, People2D]]]
) -> tuple[Rig, dict[str, Refined]]:
    """The rig with `cameras` placed again one at a time from the others (see the module)."""
    unknown = [c for c in cameras if c not in rig.names]
    if unknown:
        raise CalibrationError(
            f"--cameras: no camera {', '.join(unknown)} in the calibration "
            f"(cameras: {', '.join(rig.names)})"
        )
    kept = [n for n in rig.names if n not in cameras]
    if len(kept) < 2:
        raise CalibrationError(
            f"refining {', '.join(cameras)} leaves {len(kept)} camera(s) in place; at least 2 "
            "must stay to place the others"
        )
    done: dict[str, Refined] = {}
    for name in cameras:
        base = rig.subset([*kept, name])
        r = refine_camera(rig[name], joints_of_others(base, name, frames))
        done[name] = r
        logger.info(
            "camera %s: turned %.3f deg, moved %.3f m; %.2f px over %d joints",
            name,
            r.turned_deg,
            r.moved_m,
            r.rms_px,
            r.joints,
        )
    cams = tuple(done[c.name].camera if c.name in done else c for c in rig)
    return Rig(cams), done
