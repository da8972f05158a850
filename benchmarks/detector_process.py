"""What detection in a process of its own would cost: the detector called in the service's
process, against the same detector in a child process that takes each step's frames through
shared memory and sends the people back through a pipe.

On the real demo's 4 cameras, at their full size (1088x1920) and as 272x480 substreams (what
`serve` detects on by default with substreams), `--steps` steps each way, alternated so that
both see the same machine: ms per step (median), and the child's extra as a share of the
in-process step. The child's detector is made as `serve` makes it (backend auto). Nothing of
the product is changed by this script: it measures a design before it is built.

    python benchmarks/detector_process.py [--steps 60]

Results in results/detector_process.{json,md}.
"""

from __future__ import annotations

import argparse
import datetime
import multiprocessing as mp
import statistics
import sys
import time
from multiprocessing import shared_memory

import cv2
import numpy as np

from common import machine, save
from stereopose.detection import make_detector
from stereopose.detection.models import demo_videos

SUB = (272, 480)


def _child(conn, name: str, shapes: list[tuple[int, int, int]]) -> None:
    """The child: its own detector; per message, the step's frames read from shared memory,
    detected, and each camera's keypoints, boxes and scores sent back."""
    det = make_detector("auto")
    memory = shared_memory.SharedMemory(name=name)
    try:
        conn.send("ready")
        while True:
            msg = conn.recv()
            if msg is None:
                return
            frames, at = [], 0
            for h, w, c in shapes:
                n = h * w * c
                frames.append(np.ndarray((h, w, c), np.uint8, memory.buf[at : at + n]))
                at += n
            found = det.detect(frames)
            conn.send([(p.keypoints, p.boxes, p.scores) for p in found])
            del frames
    finally:
        memory.close()


def _frames(n: int, size: tuple[int, int] | None) -> list[list[np.ndarray]]:
    caps = [cv2.VideoCapture(str(v)) for v in demo_videos()]
    steps = []
    for _ in range(n):
        step = []
        for cap in caps:
            ok, im = cap.read()
            if not ok:
                cap.set(cv2.CAP_PROP_POS_FRAMES, 0)
                ok, im = cap.read()
            step.append(cv2.resize(im, size, interpolation=cv2.INTER_AREA) if size else im)
        steps.append(step)
    for cap in caps:
        cap.release()
    return steps


def measure(steps: list[list[np.ndarray]], det) -> dict:
    shapes = [im.shape for im in steps[0]]
    total = sum(int(np.prod(s)) for s in shapes)
    memory = shared_memory.SharedMemory(create=True, size=total)
    ctx = mp.get_context("spawn")
    parent, child_end = ctx.Pipe()
    child = ctx.Process(target=_child, args=(child_end, memory.name, shapes), daemon=True)
    child.start()
    try:
        if parent.recv() != "ready":
            raise RuntimeError("the child did not start")
        inside, outside = [], []
        for k, step in enumerate(steps):
            t0 = time.perf_counter()
            det.detect(step)
            t1 = time.perf_counter()
            at = 0
            for im in step:
                memory.buf[at : at + im.nbytes] = im.reshape(-1).data
                at += im.nbytes
            parent.send(True)
            parent.recv()
            t2 = time.perf_counter()
            if k >= 3:  # both warmed up
                inside.append(1000 * (t1 - t0))
                outside.append(1000 * (t2 - t1))
        parent.send(None)
        child.join(timeout=30)
    finally:
        if child.is_alive():
            child.kill()
        memory.close()
        memory.unlink()
    a, b = statistics.median(inside), statistics.median(outside)
    return {
        "frame_size": f"{shapes[0][1]}x{shapes[0][0]}",
        "steps": len(inside),
        "in_process_ms": a,
        "child_process_ms": b,
        "extra_share": (b - a) / a,
        "frames_mb_per_step": total / 2**20,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=60)
    args = ap.parse_args()
    if len(demo_videos()) != 4:
        sys.exit("the demo videos are not in the cache: run `stereopose demo` once")
    det = make_detector("auto")
    runs = [measure(_frames(args.steps, size), det) for size in (SUB, None)]
    for r in runs:
        print(r, flush=True)
    result = {
        "date": datetime.date.today().isoformat(),
        "machine": machine().replace("one thread", "all cores"),
        "detector": str(getattr(det, "choice", "auto")),
        "command": " ".join(["python benchmarks/detector_process.py", *sys.argv[1:]]),
        "runs": runs,
    }
    md = [
        "# Detection in a process of its own: what it would cost",
        "",
        f"{result['date']}, {result['machine']}, detector: {result['detector']}. "
        f"`{result['command']}`: the real demo's 4 cameras, each step detected in the "
        "service's process and then by the same detector in a child process (the frames "
        "through shared memory, the people back through a pipe), alternated; medians.",
        "",
        "| frames | frames per step, MB | in the process, ms/step | in a child, ms/step | extra |",
        "|---|---|---|---|---|",
    ]
    for r in runs:
        md.append(
            f"| 4 x {r['frame_size']} | {r['frames_mb_per_step']:.1f} | "
            f"{r['in_process_ms']:.1f} | {r['child_process_ms']:.1f} | "
            f"{100 * r['extra_share']:+.1f} % |"
        )
    save("detector_process", result, md)


if __name__ == "__main__":
    main()
