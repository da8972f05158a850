"""The fusion side's steps: the nodes' camera-frames grouped by capture time; late, refused
and hostile ones counted, never stepped on."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

import numpy as np
import paho.mqtt.client as paho
import pytest

from brokers import Broker
from stereopose.calibration import load_calibration
from stereopose.io.sinks.mqtt_settings import MqttSettings
from stereopose.io.source import Clock
from stereopose.nodes.fusion import NodeInput
from stereopose.nodes.wire import Topics, encode_people, encode_picture, health_message
from stereopose.site.health.watchdog import Watchdog
from stereopose.types import People2D
from waiting import wait_until

CAMS = ("cam01", "cam02", "cam03", "cam04")


@pytest.fixture
def rig(pose2sim_dir):
    return load_calibration(pose2sim_dir / "Demo_MultiPerson" / "calibration" / "Calib.qca.txt")


def _input(rig, **kw) -> NodeInput:
    settings = MqttSettings(host="127.0.0.1", site="north")
    start = time.time() - 10  # the service started 10 s ago
    return NodeInput(
        settings, rig.subset(list(CAMS)), fps=2.0, clock=Clock(time.monotonic() - 10, start), **kw
    )


def _send(inp: NodeInput, node: str, camera: str, t: float, people: int = 1) -> None:
    kp = np.zeros((people, 17, 3))
    kp[..., 0], kp[..., 1], kp[..., 2] = 100.0, 200.0, 0.9
    payload = encode_people(node, People2D(camera, 0, kp), t, (1088, 1920))
    inp._message(Topics.of("stereopose", "north").keypoints(camera), payload, False)


class Steps:
    """The input's steps, taken on a thread of their own as the service's source does."""

    def __init__(self, inp: NodeInput) -> None:
        self.inp, self.got = inp, []
        self.thread = threading.Thread(target=self._take, daemon=True)
        self.thread.start()

    def _take(self) -> None:
        for step in self.inp:
            self.got.append(step)

    def close(self) -> None:
        self.inp.end()
        self.thread.join(5)


def test_frames_of_one_capture_time_on_two_nodes_are_one_step(rig):
    inp = _input(rig)
    steps = Steps(inp)
    try:
        now = time.time()
        for k in range(3):
            t = now - 2 + k * 0.5  # the 2-Hz grid
            for cam in CAMS[:2]:
                _send(inp, "a", cam, t)
            for cam in CAMS[2:]:
                _send(inp, "b", cam, t + 0.004)  # the other node's clock 4 ms on
        wait_until(lambda: len(steps.got) >= 2, "two steps")
        first = steps.got[0]
        assert set(first.people2d) == set(CAMS)
        assert first.t == pytest.approx(now - 2 - inp.clock.start_epoch, abs=1e-3)
        assert set(first.images) == set(CAMS)  # grey pictures until the nodes send one
        assert steps.got[1].t - first.t == pytest.approx(0.5, abs=1e-3)
        assert inp.report()["partial_steps"] == 0
        # a frame of a time already given is late: counted, never a step of its own
        _send(inp, "a", "cam01", now - 2)
        assert inp.figures["cam01"].late == 1
    finally:
        steps.close()


def test_a_silent_node_delays_a_step_by_at_most_the_wait(rig):
    inp = _input(rig, wait_s=0.2)
    steps = Steps(inp)
    try:
        now = time.time()
        for cam in CAMS:  # everyone heard from: all four are waited for
            _send(inp, "a" if cam in CAMS[:2] else "b", cam, now - 3)
        wait_until(lambda: len(steps.got) == 1, "the first step")
        sent = time.monotonic()
        for cam in CAMS[:2]:  # node b says nothing more
            _send(inp, "a", cam, now - 2.5)
        wait_until(lambda: len(steps.got) == 2, "the step without node b")
        assert time.monotonic() - sent >= 0.2
        assert set(steps.got[1].people2d) == set(CAMS[:2])
        assert inp.report()["partial_steps"] == 1
        # a camera that skipped this time (a newer frame waiting) is not waited for
        _send(inp, "a", "cam01", now - 2.0)
        _send(inp, "a", "cam02", now - 2.0)
        _send(inp, "b", "cam03", now - 1.5)
        _send(inp, "b", "cam04", now - 1.5)
        wait_until(lambda: len(steps.got) == 4, "two more steps")
        assert set(steps.got[2].people2d) == set(CAMS[:2])
    finally:
        steps.close()


def test_a_node_whose_clock_is_off_is_refused_until_it_is_right(rig, caplog):
    inp = _input(rig, clock_tolerance_s=0.25)
    topic = Topics.of("stereopose", "north").node("b")
    # a retained message's clock is old: it says nothing of the node's clock now
    inp._message(topic, health_message("b", "online", clock=time.time() - 100), True)
    assert not inp.nodes["b"].refused
    inp._message(topic, health_message("b", "online", clock=time.time() + 3), False)
    assert inp.nodes["b"].refused
    assert "clock is off the service's by +3" in caplog.text
    _send(inp, "b", "cam03", time.time() - 1)
    assert inp.figures["cam03"].refused == 1 and not inp._pending["cam03"]
    for _ in range(5):
        inp._message(topic, health_message("b", "online", clock=time.time()), False)
    assert not inp.nodes["b"].refused
    _send(inp, "b", "cam03", time.time() - 0.5)
    assert len(inp._pending["cam03"]) == 1
    # a frame from the future (a node not yet heard from) is refused as well
    _send(inp, "c", "cam04", time.time() + 5)
    assert inp.figures["cam04"].refused == 1


def test_hostile_messages_are_counted_and_skipped(rig, caplog):
    inp = _input(rig)
    t = Topics.of("stereopose", "north")
    inp._message(t.keypoints("cam01"), b"\x00garbage", False)
    inp._message(t.keypoints("cam09"), b"{}", False)
    inp._message(t.picture("cam01"), encode_picture(1.0, b"\xff\xd8 not really"), False)
    inp._message(t.node("x"), b"[]", False)
    inp._message("stereopose/north/keypoints/a/b", b"{}", False)  # not a node topic
    assert inp.malformed == 3 and inp.unknown == 1
    assert "cam09" in caplog.text and "not JSON" in caplog.text
    assert not any(inp._pending.values())


def test_a_picture_from_a_node_is_the_cameras_image_in_its_steps(rig):
    import cv2

    inp = _input(rig)
    steps = Steps(inp)
    try:
        image = np.full((480, 272, 3), 200, np.uint8)
        _, jpeg = cv2.imencode(".jpg", image)
        inp._message(
            Topics.of("stereopose", "north").picture("cam01"),
            encode_picture(time.time(), jpeg.tobytes()),
            False,
        )
        _send(inp, "a", "cam01", time.time() - 1)
        wait_until(lambda: steps.got, "a step")
        assert steps.got[0].images["cam01"].shape == (480, 272, 3)
        assert inp.report()["cameras"]["cam01"]["pictures"] == 1
        # a node of another picture scale: its pictures at this camera's one size (a clip's)
        _, big = cv2.imencode(".jpg", np.full((960, 544, 3), 50, np.uint8))
        inp._message(
            Topics.of("stereopose", "north").picture("cam01"),
            encode_picture(time.time(), big.tobytes()),
            False,
        )
        t = time.time() - 0.5
        _send(inp, "a", "cam01", t)
        _send(inp, "a", "cam02", t)
        wait_until(lambda: len(steps.got) == 2, "a second step")
        assert steps.got[1].images["cam02"].shape == (480, 272, 3)  # grey, of the same size
        assert steps.got[1].images["cam01"].shape == (480, 272, 3)
        assert steps.got[1].images["cam01"].mean() < 100
    finally:
        steps.close()


def test_a_nodes_broken_health_or_a_picture_bomb_is_refused_and_the_service_goes_on(rig):
    import cv2

    from stereopose.nodes.wire import WireError, decode_health, jpeg_size

    topics = Topics.of("stereopose", "north")
    inp = _input(rig)
    steps = Steps(inp)
    try:
        # a camera's health that is not an object: refused, never kept for the rates
        for cameras in ({"cam01": 5}, {"cam01": {"fps": "fast"}}, {"cam01": {"up": "yes"}}, [1, 2]):
            bad = health_message("b", "online", clock=time.time(), cameras=cameras)
            with pytest.raises(WireError, match="cameras"):
                decode_health(bad)
            inp._message(topics.node("b"), bad, True)
        _send(inp, "b", "cam01", time.time() - 1)
        wait_until(lambda: steps.got, "a step from that node all the same")
        assert inp.rates()["cam01"] == (None, None)  # nothing of the broken health kept
        assert inp.report()["malformed"] >= 4
        # a JPEG whose header says 16000 x 16000: refused before a pixel is decoded
        _, small = cv2.imencode(".jpg", np.full((48, 64, 3), 90, np.uint8))
        jpeg = bytearray(small.tobytes())
        assert jpeg_size(bytes(jpeg)) == (64, 48)
        sof = next(i for i in range(2, len(jpeg) - 1) if jpeg[i] == 0xFF and jpeg[i + 1] == 0xC0)
        jpeg[sof + 5 : sof + 9] = (16000).to_bytes(2, "big") * 2
        assert jpeg_size(bytes(jpeg)) == (16000, 16000)
        before = inp.report()["malformed"]
        inp._message(topics.picture("cam01"), encode_picture(time.time(), bytes(jpeg)), False)
        assert inp.report()["malformed"] == before + 1
        assert inp.report()["cameras"]["cam01"]["pictures"] == 0
        with pytest.raises(WireError):
            jpeg_size(b"\xff\xd8\xff\xe0\x00")  # cut short: no frame header
    finally:
        steps.close()


def test_a_future_a_borrowed_camera_or_a_flood_never_makes_a_real_frame_late(rig, caplog):
    inp = _input(rig)
    steps = Steps(inp)
    topic = Topics.of("stereopose", "north")
    for node in ("a", "x", "y"):  # each node's clock measured right
        inp._message(topic.node(node), health_message(node, "online", clock=time.time()), False)
    try:
        now = time.time()
        real = [now - 4 + k * 0.5 for k in range(8)]  # node a's cameras on the 2-Hz grid
        for t in real:
            for cam in CAMS[:3]:
                _send(inp, "a", cam, t)
            for j in range(1, 10):  # a flood of cam01 between the grid's times
                _send(inp, "a", "cam01", t + 0.02 * j)
            _send(inp, "x", "cam02", time.time() + 0.2)  # node a's camera, from elsewhere
            _send(inp, "y", "cam04", time.time() + 0.2)  # within the clock tolerance
        wait_until(lambda: len(steps.got) >= len(real) - 1, "the real steps")
        # every real frame in a step of its own time, none late, the rest refused or dropped
        taken = [round(s.t + inp.clock.start_epoch - now, 3) for s in steps.got]
        assert taken[: len(real) - 1] == [round(t - now, 3) for t in real[:-1]]
        assert all(set(s.people2d) == set(CAMS[:3]) for s in steps.got)
        figs = inp.figures
        assert all(figs[c].late == 0 for c in CAMS)
        assert figs["cam01"].flood == 9 * len(real)
        assert figs["cam02"].refused == len(real) and figs["cam04"].refused == len(real)
        assert inp.nodes["y"].future and not inp.nodes["a"].future
        assert "keep coming from the future" in caplog.text and "which node a sends" in caplog.text
        # node y on time again: taken once as many frames in a row are
        for k in range(5):
            _send(inp, "y", "cam04", time.time() - 0.5 + 0.1 * k)
        assert not inp.nodes["y"].future
    finally:
        steps.close()


@pytest.mark.filterwarnings("ignore::pytest.PytestUnhandledThreadExceptionWarning")
def test_the_mqtt_thread_that_dies_is_started_again_and_frames_come_again(rig, tmp_path):
    broker = Broker(tmp_path / "broker").start()
    settings = MqttSettings(
        host="127.0.0.1", port=broker.port, site="north", reconnect_min_s=0.05, reconnect_max_s=0.2
    )
    inp = NodeInput(
        settings,
        rig.subset(list(CAMS)),
        fps=2.0,
        clock=Clock(time.monotonic() - 10, time.time() - 10),
    )
    dog = Watchdog(interval_s=3600)  # its rounds asked for by hand here
    pub = paho.Client(paho.CallbackAPIVersion.VERSION2, protocol=paho.MQTTv311)
    topic = Topics.of("stereopose", "north").keypoints("cam01")

    def publish(t: float) -> None:
        kp = np.zeros((1, 17, 3))
        kp[..., 0], kp[..., 1], kp[..., 2] = 100.0, 200.0, 0.9
        payload = encode_people("a", People2D("cam01", 0, kp), t, (1088, 1920))
        pub.publish(topic, payload, qos=0).wait_for_publish(5)

    try:
        with inp:
            dog.add("nodes", inp.ensure_running)
            pub.connect("127.0.0.1", broker.port)
            pub.loop_start()

            def arrives(n: int) -> Callable[[], bool]:  # sent until the n-th one arrives
                def sent() -> bool:
                    publish(time.time() - 0.1)
                    return inp.figures["cam01"].frames >= n

                return sent

            wait_until(arrives(1), "a first frame", poll_s=0.2)
            message = inp._message

            def dies(*_):  # what no `except Exception` catches: paho's thread ends
                inp._message = message
                raise SystemExit("gone")

            inp._message = dies
            n = inp.figures["cam01"].frames
            publish(time.time() - 0.1)
            wait_until(lambda: not inp.report()["running"], "paho's thread down")
            dog.check()
            assert inp.report()["restarts"] == 1 and inp.report()["running"]
            wait_until(arrives(n + 1), "a frame after the restart", poll_s=0.2)
    finally:
        pub.loop_stop()
        broker.stop()


def test_each_cameras_light_is_what_its_node_says(rig):
    """A camera's light mode as its node's health gives it (the service's console, /metrics):
    none while its node has not said, the mode once it has, from the node its frames come
    from."""
    from stereopose.nodes.node_state import nodes_light

    inp = _input(rig)
    topic = Topics.of("stereopose", "north")
    try:
        assert nodes_light(inp.report()) == {}
        now = time.time()
        cameras = {"cam01": {"light": "night"}, "cam02": {"light": "day"}, "cam03": {}}
        health = health_message("a", "online", clock=now, cameras=cameras)
        inp._message(topic.node("a"), health, False)
        for cam in ("cam01", "cam02", "cam03"):
            _send(inp, "a", cam, now)
        wait_until(lambda: inp.figures["cam03"].frames >= 1, "the cameras' frames")
        assert nodes_light(inp.report()) == {"cam01": {"mode": "night"}, "cam02": {"mode": "day"}}
    finally:
        inp.end()
