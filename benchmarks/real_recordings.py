# ruff: noqa: E501  (the results tables are written line by line)
"""The rig from people on the pose2sim wheel's two real recordings of one 4-camera rig, against
its Qualisys calibration (a part of benchmarks/calibration_people.py).

Demo_SinglePerson (one person walking, 100 frames) and Demo_MultiPerson (three people, 100
frames) share one Calib.qca.txt; the wheel's Demo_Batch/Trial_1 and Trial_2 are byte-for-byte
copies of them, so leaving one recording out of four would leave its copy in: two recordings,
each held out in turn. YOLO11n-pose detections: Demo_MultiPerson's from shared/data,
Demo_SinglePerson's made here the same way (whole frames at 640, ONNX fp32).

Figures:
- each camera's turn from cam01 against Qualisys's, for the rig from each recording and from
  both pooled;
- held-out fit: the median reprojection error (confident joints, each person triangulated from
  all its cameras) of a recording by the rig from the other, beside Qualisys's rig's;
- held-out camera: each camera's joints predicted from the other cameras' (triangulated
  without it), median error, with Qualisys's rig and the pooled one: a test of a rig that
  needs no reference;
- a camera turned 2 degrees placed again (calibrate refine) from both recordings' people.
"""

from __future__ import annotations

import time
from pathlib import Path

import cv2
import numpy as np

from stereopose.cache import cache_root
from stereopose.calibration.bundle import project_px
from stereopose.calibration.formats import load_calibration
from stereopose.calibration.people import calibrate_people, match_recordings
from stereopose.calibration.people_check import camera_fit_px, fit_px
from stereopose.calibration.people_match import triangulate_groups
from stereopose.calibration.poses import intrinsics_row, pose_change, rig_poses
from stereopose.calibration.refine import refine_rig
from stereopose.cli import main as cli
from stereopose.cli.calibrate_site import _frames
from stereopose.io.pose2sim_data import pose2sim_demo_dir
from stereopose.types import Camera, Rig

NAMES = ("Demo_SinglePerson", "Demo_MultiPerson")


def _single_pose() -> Path:
    out = cache_root() / "bench" / "single_person_pose"
    if not (out / "cam04_json").is_dir():
        videos = pose2sim_demo_dir() / "Demo_SinglePerson" / "videos"
        args = ["detect", "--videos", *(str(videos / f"cam0{i}.mp4") for i in range(1, 5))]
        args += ["--out", str(out), "--no-regions", "--backend", "onnx", "--precision", "fp32"]
        assert cli([*args, "--overwrite"]) == 0
    return out


def turns(rig: Rig, ref: Rig) -> dict[str, float]:
    out = {}
    for n in ref.names:
        a, b = rig[n].R @ rig["cam01"].R.T, ref[n].R @ ref["cam01"].R.T
        out[n] = float(np.degrees(np.linalg.norm(cv2.Rodrigues(a @ b.T)[0])))
    return out


def _held_out_camera(m, poses: np.ndarray, intr: np.ndarray) -> dict[str, float]:
    """Each camera's confident joints predicted from the other cameras of its group (three
    views or more), median pixel error."""
    v, C = m.views, len(poses)
    out = {}
    for c in range(C):
        errs = []
        for g in m.groups:
            if c not in g or len(g) < 3:
                continue
            X = triangulate_groups(v, [g], poses, np.array([k in g and k != c for k in range(C)]))[
                0
            ]
            kp = v.det[g[c]][2]
            ok = np.isfinite(X[:, 0]) & (kp[:, 2] >= 0.5)
            if ok.any():
                uv, _ = project_px(
                    np.repeat(poses[c : c + 1], ok.sum(), 0),
                    np.repeat(intr[c : c + 1], ok.sum(), 0),
                    X[ok],
                )
                errs.append(np.linalg.norm(uv - kp[ok, :2], axis=1))
        out[v.cameras[c]] = float(np.median(np.concatenate(errs))) if errs else float("nan")
    return out


def _turned(c: Camera, deg: float) -> Camera:
    axis = np.array([0.3, 1.0, 0.2]) / np.linalg.norm([0.3, 1.0, 0.2])
    R = cv2.Rodrigues(np.radians(deg) * axis)[0] @ c.R
    return Camera(
        c.name, c.size, c.matrix, c.distortions, cv2.Rodrigues(R)[0].ravel(), -R @ c.center
    )


def real_recordings(demo: Path) -> dict:
    ref = load_calibration(demo / "calib.toml")
    cams = {c.name: c for c in ref}
    intr = np.stack([intrinsics_row(c) for c in ref])
    frames = [_frames(_single_pose(), ref, 600), _frames(demo / "pose", ref, 600)]
    parts, _ = match_recordings(frames, cams)
    d = float(np.linalg.norm(ref["cam01"].center - ref["cam03"].center))
    scale = {"distance": ("cam01", "cam03", d)}
    res: dict = {
        "recordings": list(NAMES),
        "frames": [len(f) for f in frames],
        "qualisys": {},
        "from": {},
    }
    for i, m in enumerate(parts):
        res["qualisys"][NAMES[i]] = {
            "fit_px": fit_px(m.views, m.groups, rig_poses(ref), intr),
            "camera_fit_px": camera_fit_px(m.views, m.groups, rig_poses(ref), intr),
            "held_out_camera_px": _held_out_camera(m, rig_poses(ref), intr),
        }
    for i in range(2):
        t0 = time.perf_counter()
        r = calibrate_people(frames[i], ref, **scale)
        other = parts[1 - i]
        res["from"][NAMES[i]] = {
            "seconds": time.perf_counter() - t0,
            "turn_deg": turns(r.rig, ref),
            "judged_on": NAMES[1 - i],
            "held_out_px": fit_px(other.views, other.groups, rig_poses(r.rig), intr),
            "held_out_camera_fit_px": camera_fit_px(
                other.views, other.groups, rig_poses(r.rig), intr
            ),
        }
    t0 = time.perf_counter()
    r = calibrate_people(frames, ref, **scale)
    res["pooled"] = {
        "seconds": time.perf_counter() - t0,
        "turn_deg": turns(r.rig, ref),
        "held_out_all_px": {NAMES[k]: v for k, v in r.held_out_all_px.items()},
        "fit_px": {
            NAMES[i]: fit_px(m.views, m.groups, rig_poses(r.rig), intr) for i, m in enumerate(parts)
        },
        "held_out_camera_px": {
            NAMES[i]: _held_out_camera(m, rig_poses(r.rig), intr) for i, m in enumerate(parts)
        },
        "point_like": r.point_like,
        "warnings": [w for w in r.warnings if "point" in w],
    }
    pooled = frames[0] + [(n + 10**6, p) for n, p in frames[1]]
    res["turned_2deg"] = {}
    for name in ref.names:
        knocked = Rig(tuple(_turned(c, 2.0) if c.name == name else c for c in ref))
        new, _ = refine_rig(knocked, [name], pooled)
        res["turned_2deg"][name] = pose_change(ref[name], new[name])[0]
    return res


def _slash(d: dict, keys) -> str:
    return " / ".join(f"{d[k]:.2f}" for k in keys)


def lines(res) -> list[str]:
    head = [
        "## Two real recordings of one rig (pose2sim), each held out in turn, against Qualisys",
        "",
    ]
    if not isinstance(res, dict):
        return [*head, f"- {res}", ""]
    n = list(res["qualisys"][NAMES[0]]["camera_fit_px"])
    q = res["qualisys"]
    out = [
        *head,
        f"Demo_SinglePerson ({res['frames'][0]} frames, one person walking) and Demo_MultiPerson ({res['frames'][1]} frames, "
        "three people); the wheel's Demo_Batch trials are copies of these two. Scale: the distance cam01-cam03.",
        "",
        "| rig | turn from cam01 against Qualisys's, deg ("
        + ", ".join(n[1:])
        + ") | judged on | held-out fit px | Qualisys's fit there px | per camera px (Qualisys's) |",
        "|---|---|---|---|---|---|",
    ]
    for src, f in res["from"].items():
        j = f["judged_on"]
        per = ", ".join(
            f"{f['held_out_camera_fit_px'][c]:.1f} ({q[j]['camera_fit_px'][c]:.1f})" for c in n
        )
        out.append(
            f"| from {src} | {_slash(f['turn_deg'], n[1:])} | {j} | "
            f"{f['held_out_px']:.2f} | {q[j]['fit_px']:.2f} | {per} |"
        )
    p = res["pooled"]
    out += [
        "",
        f"Both pooled ({p['seconds']:.0f} s, with the held-out rigs): turns {_slash(p['turn_deg'], n[1:])} deg; "
        "fit on each recording "
        + ", ".join(
            f"{k} {v:.2f} px (Qualisys's {q[k]['fit_px']:.2f})" for k, v in p["fit_px"].items()
        )
        + "; point-like joints per camera "
        + ", ".join(f"{k} {v}" for k, v in p["point_like"].items())
        + ".",
        "",
        "Held-out camera (each camera's joints predicted from the other cameras', median px), Qualisys's rig / the pooled rig:",
        "",
        "| recording | " + " | ".join(n) + " |",
        "|---|" + "---|" * len(n),
    ]
    for k in NAMES:
        out.append(
            f"| {k} | "
            + " | ".join(
                f"{q[k]['held_out_camera_px'][c]:.1f} / {p['held_out_camera_px'][k][c]:.1f}"
                for c in n
            )
            + " |"
        )
    out += [
        "",
        "A camera turned 2 deg in the file, placed again (`calibrate refine`, both recordings): degrees off Qualisys's after: "
        + ", ".join(f"{k} {v:.2f}" for k, v in res["turned_2deg"].items()),
        "",
        RECORDINGS_NOTES,
    ]
    return out


RECORDINGS_NOTES = """**Reading it.** A rig from one recording predicts the other about as well as Qualisys's does
(within a pixel of it, better on one), and the pooled rig fits both better than Qualisys's; the
turns against Qualisys stay at 1-4 degrees. These detections do not support Qualisys's poses
to that degree: with Qualisys's rig, each camera's joints predicted from the other cameras
miss by 20-70 px, more than with the rig from people, and with a shift common to the whole
person (16 px on cam01 in one recording, 47 px in the other). Placed again from the others'
people, a camera settles 0.5-3.5 degrees from Qualisys's pose whatever it starts from. Two
recordings of 100 frames each, with a nano detector at 640 px on 1920 px frames, cannot tell a
pose to half a degree against this reference."""
