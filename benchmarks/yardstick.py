"""The yardstick: multi-camera 3D poses the straightforward way, in pure Python.

What `stereopose reconstruct --no-tracking` does, written as one would first write it: the
standard library only (json, math, tomllib), lists, one frame at a time. For each frame:
undistort every keypoint (OpenCV's iterative model), group people across cameras by the
epipolar constraint (per camera pair, the mean symmetric point-to-epipolar-line distance in
pixels over the joints confident in both; pairs merged greedily, cheapest first, never two
people of one camera in a group), triangulate each joint with the all-view DLT (confidence-
weighted least squares over every view of the group that sees it, 3x3 normal equations), and
write the 3D poses as JSON lines (docs/formats.md). Ids are per frame.

usage: python benchmarks/yardstick.py CALIB.toml POSE_DIR OUT.jsonl [--fps 25]
"""

from __future__ import annotations

import argparse
import json
import math
import re
from pathlib import Path

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib  # type: ignore[no-redef]

NUM_JOINTS = 17
MIN_CONF = 0.3  # joints below this confidence take no part
MAX_PAIR_PX = 20.0  # mean symmetric epipolar distance accepted for a pair of people
MIN_COMMON = 3  # joints confident in both people of a pair
MIN_JOINTS = 5  # a 3D person needs this many triangulated joints
HIPS = (11, 12)


def rodrigues(r: list[float]) -> list[list[float]]:
    theta = math.sqrt(sum(v * v for v in r))
    if theta < 1e-12:
        return [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
    x, y, z = (v / theta for v in r)
    c, s, C = math.cos(theta), math.sin(theta), 1.0 - math.cos(theta)
    return [
        [c + x * x * C, x * y * C - z * s, x * z * C + y * s],
        [y * x * C + z * s, c + y * y * C, y * z * C - x * s],
        [z * x * C - y * s, z * y * C + x * s, c + z * z * C],
    ]


def load_cameras(path: Path) -> list[dict]:
    cams = []
    for table in tomllib.loads(path.read_text()).values():
        if not isinstance(table, dict) or "matrix" not in table:
            continue
        rot = table["rotation"]
        R = rot if isinstance(rot[0], list) else rodrigues(rot)
        K = table["matrix"]
        d = [*table["distortions"], 0.0][:5]
        cams.append({"name": table["name"], "K": K, "d": d, "R": R, "t": table["translation"]})
    return cams


def undistort(u: float, v: float, cam: dict) -> tuple[float, float]:
    """Distorted pixel -> ideal normalised coordinates (cv2.undistortPoints' iteration)."""
    K, (k1, k2, p1, p2, k3) = cam["K"], cam["d"]
    y0 = (v - K[1][2]) / K[1][1]
    x0 = (u - K[0][2] - K[0][1] * y0) / K[0][0]
    x, y = x0, y0
    for _ in range(30):
        r2 = x * x + y * y
        icdist = 1.0 / (1.0 + ((k3 * r2 + k2) * r2 + k1) * r2)
        xn = (x0 - (2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x))) * icdist
        yn = (y0 - (p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y)) * icdist
        done = abs(xn - x) + abs(yn - y) < 1e-12
        x, y = xn, yn
        if done:
            break
    return x, y


def essential(a: dict, b: dict) -> list[list[float]]:
    """E with x_b^T E x_a = 0 for normalised points of cameras a and b."""
    Ra, Rb = a["R"], b["R"]
    R = [[sum(Rb[i][k] * Ra[j][k] for k in range(3)) for j in range(3)] for i in range(3)]
    t = [b["t"][i] - sum(R[i][k] * a["t"][k] for k in range(3)) for i in range(3)]
    tx = [[0.0, -t[2], t[1]], [t[2], 0.0, -t[0]], [-t[1], t[0], 0.0]]
    return [[sum(tx[i][k] * R[k][j] for k in range(3)) for j in range(3)] for i in range(3)]


def pair_cost(pa: list, pb: list, E: list, fa: float, fb: float) -> float:
    """Mean symmetric point-to-epipolar-line distance (pixels) over joints confident in both."""
    total, n = 0.0, 0
    for ja, jb in zip(pa, pb, strict=True):
        if ja is None or jb is None:
            continue
        (xa, ya, _), (xb, yb, _) = ja, jb
        lb = [E[i][0] * xa + E[i][1] * ya + E[i][2] for i in range(3)]  # line in b
        la = [E[0][i] * xb + E[1][i] * yb + E[2][i] for i in range(3)]  # line in a
        db = abs(lb[0] * xb + lb[1] * yb + lb[2]) / math.hypot(lb[0], lb[1])
        da = abs(la[0] * xa + la[1] * ya + la[2]) / math.hypot(la[0], la[1])
        total += 0.5 * (fa * da + fb * db)
        n += 1
    return total / n if n >= MIN_COMMON else math.inf


def group(people: dict[int, list], cams: list[dict], ess: dict) -> list[dict[int, int]]:
    """Greedy grouping: groups {camera index: person index} of two people or more."""
    edges = []
    views = sorted(people)
    for i, a in enumerate(views):
        for b in views[i + 1 :]:
            fa, fb = cams[a]["K"][0][0], cams[b]["K"][0][0]
            for p, pa in enumerate(people[a]):
                for q, pb in enumerate(people[b]):
                    cost = pair_cost(pa, pb, ess[a, b], fa, fb)
                    if cost <= MAX_PAIR_PX:
                        edges.append((cost, a, p, b, q))
    edges.sort()
    group_of: dict[tuple[int, int], dict[int, int]] = {}
    for _, a, p, b, q in edges:
        ga = group_of.get((a, p)) or {a: p}
        gb = group_of.get((b, q)) or {b: q}
        if ga is gb or set(ga) & set(gb):
            continue  # already together, or two people of one camera
        ga.update(gb)
        for key in ga.items():
            group_of[key] = ga
    unique = {id(g): g for g in group_of.values()}
    return list(unique.values())


def solve3(A: list[list[float]], b: list[float]) -> list[float] | None:
    """Gaussian elimination with partial pivoting on a 3x3 system."""
    M = [[*A[i], b[i]] for i in range(3)]
    for c in range(3):
        r = max(range(c, 3), key=lambda i: abs(M[i][c]))
        if abs(M[r][c]) < 1e-12:
            return None
        M[c], M[r] = M[r], M[c]
        for i in range(c + 1, 3):
            f = M[i][c] / M[c][c]
            M[i] = [M[i][k] - f * M[c][k] for k in range(4)]
    x = [0.0, 0.0, 0.0]
    for i in (2, 1, 0):
        x[i] = (M[i][3] - sum(M[i][k] * x[k] for k in range(i + 1, 3))) / M[i][i]
    return x


def triangulate(obs: list[tuple[float, float, float, dict]]) -> list[float] | None:
    """All-view DLT: rows c (x P3 - P1), c (y P3 - P2), least squares for (X, Y, Z)."""
    N = [[0.0] * 3 for _ in range(3)]
    rhs = [0.0, 0.0, 0.0]
    for x, y, c, cam in obs:
        R, t = cam["R"], cam["t"]
        for m, i in ((x, 0), (y, 1)):  # m (R2 X + t2) = Ri X + ti
            a = [c * (m * R[2][k] - R[i][k]) for k in range(3)]
            r = c * (t[i] - m * t[2])
            for u in range(3):
                rhs[u] += a[u] * r
                for w in range(3):
                    N[u][w] += a[u] * a[w]
    X = solve3(N, rhs)
    if X is None:
        return None
    for _, _, _, cam in obs:  # in front of every camera that saw it
        R, t = cam["R"], cam["t"]
        if sum(R[2][k] * X[k] for k in range(3)) + t[2] <= 0.0:
            return None
    return X


def reconstruct_frame(people: dict[int, list], cams: list[dict], ess: dict) -> list[dict]:
    out = []
    for g in group(people, cams, ess):
        joints, conf = [], []
        for j in range(NUM_JOINTS):
            obs = [(*people[a][p][j], cams[a]) for a, p in g.items() if people[a][p][j]]
            X = triangulate(obs) if len(obs) >= 2 else None
            joints.append(None if X is None else [round(v, 4) for v in X])
            conf.append(round(sum(o[2] for o in obs) / len(obs), 3) if X else 0.0)
        if sum(j is not None for j in joints) < MIN_JOINTS:
            continue
        hips = [joints[h] for h in HIPS if joints[h]] or [j for j in joints if j]
        position = [round(sum(h[i] for h in hips) / len(hips), 4) for i in (0, 1)]
        out.append({"id": len(out) + 1, "joints": joints, "conf": conf, "position": position})
    return out


def read_people(path: Path, cam: dict) -> list[list]:
    """People of one file: 17 undistorted (x, y, c) or None (missing, or below MIN_CONF)."""
    people = []
    for person in json.loads(path.read_text())["people"]:
        v = person["pose_keypoints_2d"]
        people.append(
            [
                (*undistort(v[3 * j], v[3 * j + 1], cam), v[3 * j + 2])
                if v[3 * j + 2] is not None and v[3 * j + 2] >= MIN_CONF
                else None
                for j in range(NUM_JOINTS)
            ]
        )
    return people


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("calib", type=Path)
    ap.add_argument("pose_dir", type=Path)
    ap.add_argument("out", type=Path)
    ap.add_argument("--fps", type=float, default=25.0)
    args = ap.parse_args()
    cams = load_cameras(args.calib)
    files: list[dict[int, Path]] = []
    for cam in cams:
        folder = args.pose_dir / f"{cam['name']}_json"
        numbers = {p: re.findall(r"\d+", p.stem) for p in folder.glob("*.json")}
        files.append({int(n[-1]): p for p, n in numbers.items() if n})
    ess = {
        (a, b): essential(cams[a], cams[b])
        for a in range(len(cams))
        for b in range(a + 1, len(cams))
    }
    with open(args.out, "w", encoding="utf-8") as f:
        for frame in sorted(set().union(*files)):
            people = {
                c: read_people(fs[frame], cams[c]) for c, fs in enumerate(files) if frame in fs
            }
            rec = {"frame": frame, "t": round(frame / args.fps, 4)}
            rec["people"] = reconstruct_frame(people, cams, ess)
            f.write(json.dumps(rec) + "\n")


if __name__ == "__main__":
    main()
