"""A node detecting in regions: distant workers in a wide 1080p view (the real demo's frames
shrunk into it, the calibration scaled to match), found and published where whole frames at
640 find nobody; its health says how much of whole frames' model input the regions took."""

from __future__ import annotations

import threading

import cv2
import numpy as np
import pytest

from brokers import Broker, Subscriber
from stereopose.calibration.formats import load_calibration, save_calibration
from stereopose.detection import make_detector
from waiting import wait_until

pytestmark = [pytest.mark.slow, pytest.mark.realdata]


def _far_video(src, path, distant, frames: int) -> list[np.ndarray]:
    cap = cv2.VideoCapture(str(src), cv2.CAP_FFMPEG)
    shown = []
    out = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), 30.0, distant.canvas)
    for _ in range(frames):
        ok, im = cap.read()
        if not ok:
            break
        far = distant.frame(im)
        shown.append(far)
        out.write(far)
    out.release()
    cap.release()
    return shown


def test_a_node_finds_distant_workers_in_regions(tmp_path, pose2sim_dir):
    from stereopose.nodes.node import DetectNode, plan_node
    from stereopose.nodes.wire import decode_health, decode_people
    from stereopose.sim.distant import Distant

    demo = pose2sim_dir / "Demo_MultiPerson"
    far = Distant(0.2)  # the workers 120-200 px tall in 1920x1080
    calib = tmp_path / "far.toml"
    save_calibration(calib, far.rig(load_calibration(demo / "calibration" / "Calib.qca.txt")))
    video = tmp_path / "cam04.mp4"
    shown = _far_video(demo / "videos" / "cam04.mp4", video, far, 60)
    # whole frames at 640 lose them in this camera: what the node's regions are for
    whole = make_detector("onnx", threads=2)
    assert sum(len(p) for p in whole.detect(shown[:10:3])) <= 1
    broker = Broker(tmp_path / "broker").start()
    config = tmp_path / "serve.toml"
    config.write_text(
        f'calibration = "{calib}"\noutput = "{tmp_path / "data"}"\n\n'
        "[input]\ndetect_fps = 4.0\n\n"
        f'[mqtt]\nhost = "127.0.0.1"\nport = {broker.port}\nsite = "north"\n\n'
        f'[[cameras]]\nname = "cam04"\nsource = "{video}"\nloop = true\n\n'
        f'[[cameras]]\nname = "cam01"\nsource = "{video}"\nloop = true\n'
    )
    sub = Subscriber(broker.port, "stereopose/north/keypoints/+", "stereopose/north/nodes/+")
    node = DetectNode(plan_node(config, ["cam04"], name="far-1"))
    assert node.regions is not None  # [detector] regions is the default
    halt = threading.Event()
    runner = threading.Thread(target=node.run, args=(halt,))
    runner.start()
    try:

        def frames() -> list:
            return [
                decode_people(p.encode(), "cam04")
                for p in sub.on("stereopose/north/keypoints/cam04")
            ]

        wait_until(lambda: len(frames()) >= 8, "eight camera-frames on the broker", 90, 0.1)
        people = [len(k.people.keypoints) for k in frames()]
        # the two workers in (almost) every frame after the first (the node's first step, its
        # regions not yet on them); the bystander comes and goes
        assert sum(n >= 2 for n in people[1:]) >= 0.9 * len(people[1:]), people
        kp = np.concatenate([k.people.keypoints for k in frames()])
        seen = kp[..., 2] > 0.5
        x, y = kp[seen][:, 0], kp[seen][:, 1]  # in the canvas, where the frames were pasted
        assert x.min() >= far.at[0] - 5 and y.min() >= far.at[1] - 5
        assert x.max() <= far.at[0] + 1088 * 0.2 + 5 and y.max() <= far.at[1] + 1920 * 0.2 + 5

        def health() -> dict:
            msgs = sub.on("stereopose/north/nodes/far-1")
            return dict(decode_health(msgs[-1].encode())) if msgs else {}

        wait_until(
            lambda: (health().get("regions") or {}).get("cam04"), "the node's regions", 20, 0.1
        )
        regions = health()["regions"]["cam04"]
        assert regions["full_scans"] >= 1 and regions["regions"] >= 1
        # its first scan took the whole frame and every tile; then a region a step: the share
        # of whole frames' model input falls under one
        wait_until(
            lambda: 0 < health()["regions"]["cam04"]["input_share"] < 1.0,
            "less model input than whole frames at 640",
            60,
            0.2,
        )
    finally:
        halt.set()
        runner.join(30)
        sub.close()
        broker.stop()
    assert not runner.is_alive()
