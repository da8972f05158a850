"""Writing a simulated scene to disk in the project's file formats."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from stereopose.sim.scene import Scene


def write_scene(scene: Scene, out_dir: str | Path) -> None:
    """Write `out_dir/calib.toml`, `out_dir/pose/<camera>_json/...` (every frame and camera,
    empty people lists included) and `out_dir/truth.jsonl` (one line per frame, joints in
    metres, null where missing)."""
    from stereopose.calibration.formats import save_calibration
    from stereopose.detection.openpose import write_pose_frame

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    meta = {"simulated": True, "seed": scene.seed, "difficulty": scene.difficulty}
    save_calibration(out / "calib.toml", scene.rig, metadata=meta)
    pose_dir = out / "pose"
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
