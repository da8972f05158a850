"""A node carries steps as `serve` does, never where the fusion service holds a camera: the
real demo's two cameras played at a node with a real broker; the fusion service's side played
by its HoldTeller's messages. Told nothing, the node carries nothing; told that one camera sees
someone near a live zone, it carries the other's slow steps and never that one's."""

from __future__ import annotations

import json
import threading

import pytest

from brokers import Broker, Subscriber
from stereopose.nodes.hold import encode_hold
from waiting import wait_until

pytestmark = [pytest.mark.slow, pytest.mark.realdata]


def _carry(sub: Subscriber) -> dict:
    """The node's last health's carried-step figures ({} before any)."""
    said = sub.on("stereopose/north/nodes/carry-1")
    return json.loads(said[-1]).get("carry") or {} if said else {}


def _cameras(sub: Subscriber) -> dict:
    return _carry(sub).get("cameras", {})


def test_a_node_carries_only_what_the_fusion_service_lets_it(tmp_path, pose2sim_dir):
    from stereopose.nodes.node import DetectNode, plan_node

    demo = pose2sim_dir / "Demo_MultiPerson"
    broker = Broker(tmp_path / "broker").start()
    config = tmp_path / "serve.toml"
    config.write_text(
        f'calibration = "{demo / "calibration" / "Calib.qca.txt"}"\n'
        f'output = "{tmp_path / "data"}"\n\n[input]\ndetect_fps = 10.0\n\n'
        # the demo's people at a bay, slow enough to be carried (the rule under test is the
        # hazard's, not the motion's)
        "[detector]\ncarry_motion = 0.25\n\n"
        f'[mqtt]\nhost = "127.0.0.1"\nport = {broker.port}\nsite = "north"\n\n'
        f'[[cameras]]\nname = "cam01"\nsource = "{demo / "videos" / "cam01.mp4"}"\nloop = true\n\n'
        f'[[cameras]]\nname = "cam02"\nsource = "{demo / "videos" / "cam02.mp4"}"\nloop = true\n'
    )
    sub = Subscriber(broker.port, "stereopose/north/nodes/+")
    node = DetectNode(plan_node(config, ["cam01", "cam02"], name="carry-1"))
    assert node.carry is not None  # [detector] carry is the default
    halt = threading.Event()
    runner = threading.Thread(target=node.run, args=(halt,))
    runner.start()
    told = threading.Event()

    def fusion() -> None:  # the fusion service's holds: cam02 sees someone near the busbar
        while not halt.is_set():
            if told.is_set():
                broker_client.publish("stereopose/north/hold", encode_hold(0.0, ["cam02"], False))
            halt.wait(0.1)

    import paho.mqtt.client as paho

    broker_client = paho.Client(paho.CallbackAPIVersion.VERSION2)
    broker_client.connect("127.0.0.1", broker.port)
    broker_client.loop_start()
    teller = threading.Thread(target=fusion)
    teller.start()
    try:
        # told nothing: every step detected, those it would have carried counted as held
        wait_until(
            lambda: sum(c["detected"] for c in _cameras(sub).values()) >= 16,
            "eight steps of two cameras detected",
            timeout_s=120,
            poll_s=0.2,
        )
        quiet = _cameras(sub)
        assert all(c["carried"] == 0 for c in quiet.values()), quiet
        assert sum(c["near_hazard"] for c in quiet.values()) > 0, quiet  # held, not fast
        told.set()
        wait_until(
            lambda: _cameras(sub).get("cam01", {}).get("carried", 0) >= 2,
            "cam01's slow steps carried",
            timeout_s=120,
            poll_s=0.2,
        )
        now = _cameras(sub)
        assert now["cam02"]["carried"] == 0, now  # held by the fusion service, at every step
        assert now["cam02"]["near_hazard"] > quiet["cam02"]["near_hazard"], (quiet, now)
        holds = _carry(sub)["holds"]
        assert holds["taken"] > 0 and holds["malformed"] == 0
    finally:
        halt.set()
        runner.join(30)
        teller.join(5)
        broker_client.loop_stop()
        broker_client.disconnect()
        sub.close()
        broker.stop()
    assert not runner.is_alive()
