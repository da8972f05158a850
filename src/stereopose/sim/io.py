"""Writing a simulated scene to disk in the project's file formats."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np

from stereopose.errors import StereoposeError
from stereopose.sim.scene import Scene


def write_scene(scene: Scene, out_dir: str | Path) -> None:
    """Write `out_dir/calib.toml`, `out_dir/pose/<camera>_json/...` (every frame and camera,
    empty people lists included) and `out_dir/truth.jsonl` (one line per frame, joints in
    metres, null where missing). Camera folders of a scene written there before are replaced;
    a `pose` folder holding anything else is an error."""
    from stereopose.calibration.formats import save_calibration
    from stereopose.detection.openpose import write_pose_frame

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    pose_dir = out / "pose"
    if pose_dir.is_dir():
        # A scene written here before would mix its frames and cameras into this one.
        stale = list(pose_dir.iterdir())
        foreign = [p.name for p in stale if not (p.is_dir() and p.name.endswith("_json"))]
        if foreign:
            raise StereoposeError(
                f"{pose_dir}: not a keypoints folder written by stereopose "
                f"(holds {', '.join(sorted(foreign)[:5])}); choose another output folder"
            )
        for p in stale:
            shutil.rmtree(p)
    meta = {"simulated": True, "seed": scene.seed, "difficulty": scene.difficulty}
    save_calibration(out / "calib.toml", scene.rig, metadata=meta)
    for frame in scene.detections:
        for name in scene.rig.names:
            write_pose_frame(pose_dir, name, frame[name])
    with open(out / "truth.jsonl", "w", encoding="utf-8", newline="\n") as f:
        for t in range(scene.num_frames):
            people = []
            for n in np.flatnonzero(scene.present[t]):
                joints = [
                    [float(v) for v in j] if np.all(np.isfinite(j)) else None
                    for j in scene.truth[t, n]
                ]
                people.append({"id": int(scene.ids[n]), "joints": joints})
            f.write(json.dumps({"frame": t, "t": t / scene.fps, "people": people}) + "\n")
