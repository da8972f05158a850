"""A node on live cameras: real ffmpeg HTTP streams of the demo, a real broker, the node run
as `detect-node` runs it (DetectNode on its thread)."""

from __future__ import annotations

import json
import subprocess
import threading

import numpy as np
import pytest

from brokers import Broker, Subscriber
from streams import ffmpeg, free_port, serve, stop, wait_serving
from waiting import wait_until


@pytest.mark.slow
@pytest.mark.realdata
def test_a_node_publishes_a_live_cameras_people_in_calibrated_pixels(tmp_path, pose2sim_dir):
    from stereopose.detection import choose
    from stereopose.nodes.node import DetectNode, plan_node
    from stereopose.nodes.wire import decode_health, decode_people

    demo = pose2sim_dir / "Demo_MultiPerson"
    small = tmp_path / "cam01-small.mp4"  # the camera's substream: a quarter of its size
    subprocess.run(
        [
            ffmpeg(),
            "-loglevel",
            "error",
            "-y",
            "-i",
            str(demo / "videos" / "cam01.mp4"),
            "-vf",
            "scale=272:480",
            "-an",
            "-c:v",
            "mpeg4",
            "-q:v",
            "3",
            str(small),
        ],
        check=True,
    )
    broker = Broker(tmp_path / "broker").start()
    ports = [free_port(), free_port()]
    servers = [serve(small, ports[0], "main", "mpeg4"), serve(small, ports[1], "sub", "mpeg4")]
    wait_serving(servers, ports)
    config = tmp_path / "serve.toml"
    config.write_text(
        f'calibration = "{demo / "calibration" / "Calib.qca.txt"}"\n'
        f'output = "{tmp_path / "data"}"\n\n[input]\ndetect_fps = 4.0\n\n'
        f'[serve]\ncamera_timeout_s = 2.0\n\n[mqtt]\nhost = "127.0.0.1"\nport = {broker.port}\n'
        'site = "north"\n\n'
        f'[[cameras]]\nname = "cam01"\nsource = "http://127.0.0.1:{ports[0]}/main.ts"\n'
        f'detect = "http://127.0.0.1:{ports[1]}/sub.ts"\n\n'
        f'[[cameras]]\nname = "cam02"\nsource = "{demo / "videos" / "cam02.mp4"}"\n'
    )
    sub = Subscriber(broker.port, "stereopose/north/keypoints/+", "stereopose/north/nodes/+")
    node = DetectNode(plan_node(config, ["cam01"], name="edge-1"))
    halt = threading.Event()
    runner = threading.Thread(target=node.run, args=(halt,))
    runner.start()
    try:

        def frames() -> list:
            return [
                decode_people(p.encode(), "cam01")
                for p in sub.on("stereopose/north/keypoints/cam01")
            ]

        wait_until(
            lambda: sum(len(k.people.keypoints) for k in frames()) >= 3,
            "people of the live camera on the broker",
            60,
            0.1,
        )
        got = frames()
        kp = np.concatenate([k.people.keypoints for k in got])
        seen = kp[..., 2] > 0.5
        # found on the 272x480 substream, sent in the calibration's 1088x1920 pixels
        assert kp[seen][:, 0].max() > 300 and kp[seen][:, 1].max() > 600
        assert all(k.size == (1088, 1920) and k.node == "edge-1" for k in got)
        times = [k.t for k in got]
        assert times == sorted(times)

        def health() -> dict:
            msgs = sub.on("stereopose/north/nodes/edge-1")
            return dict(decode_health(msgs[-1].encode())) if msgs else {}

        wait_until(
            lambda: health().get("cameras", {}).get("cam01", {}).get("up") is True,
            "the node's health: cam01 up",
            20,
            0.1,
        )
        assert health()["backend"] == choose().backend and health()["detect_ms"] > 0
        stop(servers)  # the camera goes away: the node says so, and goes on
        wait_until(
            lambda: health().get("cameras", {}).get("cam01", {}).get("up") is False,
            "the node's health: cam01 down",
            30,
            0.1,
        )
    finally:
        halt.set()
        runner.join(30)
        stop(servers)
        sub.close()
        broker.stop()
    assert not runner.is_alive()
    assert node.publisher is not None and node.publisher.counts.dropped == 0
    # the clean stop says offline, retained
    assert json.loads(sub.on("stereopose/north/nodes/edge-1")[-1])["state"] == "offline"
    assert node.publisher.counts.pictures >= 1  # a picture a second (JPEG: not text)
