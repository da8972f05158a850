"""The frame loop's own parts under `serve` (site.run_parts): made once the sinks are open, in
their start order (the keeper, the outbox, the warnings on site, the watchdog), attached to
the API's desks as they start and detached as they close; the watchdog made with the
receivers it watches (the nodes' MQTT client, the outbox's), each started again should its
thread die, with a real broker."""

from __future__ import annotations

import json

import paho.mqtt.client as paho
import pytest

from brokers import Broker, free_port
from stereopose.nodes.fusion import NodeInput
from stereopose.nodes.wire import Topics
from stereopose.pipeline.demo import write_serve_demo_config
from stereopose.site.health.calib_health import CalibrationHealth
from stereopose.site.health.calib_keeper import CalibrationKeeper
from stereopose.site.parts import StatusSink
from stereopose.site.plan import plan_serve
from stereopose.site.restart import Resume
from stereopose.site.run_parts import RunParts
from stereopose.site.run_sinks import RunSinks
from stereopose.site.service import SiteService
from waiting import wait_until

pytestmark = pytest.mark.realdata


@pytest.fixture
def served(tmp_path):
    broker = Broker(tmp_path / "broker").start()
    config = write_serve_demo_config(tmp_path / "demo", tmp_path / "data", free_port(), imgsz=320)
    mqtt = f'[mqtt]\nhost = "127.0.0.1"\nport = {broker.port}\nsite = "demo"\n\n[serve]\n'
    config.write_text(config.read_text().replace("[serve]\n", mqtt, 1))
    plan = plan_serve(config)
    service = SiteService(plan, Resume.from_log(plan.events_db))
    service.start()
    yield service
    service.close()
    broker.stop()


@pytest.mark.filterwarnings("ignore::pytest.PytestUnhandledThreadExceptionWarning")
def test_the_loops_parts_attach_in_order_and_the_watchdog_restarts_their_receivers(served):
    plan = served.plan
    assert plan.mqtt is not None
    cam = plan.rig.names[0]
    keeper = CalibrationKeeper(plan.rig, plan.calib_path, CalibrationHealth(plan.rig))
    status = StatusSink(plan.status_path, served.report.snapshot, 1.0)
    nodes = NodeInput(plan.mqtt, plan.rig, fps=2.0, clock=served.clock)
    with nodes:
        run = RunParts(served, plan.config, RunSinks([], (), None, None, status), keeper, nodes)
        assert [p.name for p in run.parts.order] == [
            "the calibration keeper",
            "the outbox",
            "the warnings on site",
            "the watchdog",
        ]
        assert run.outbox is not None and run.onsite is not None
        assert served.calibration_desk.keeper is None and served.warnings.onsite is None
        try:
            run.parts.start()
            assert served.calibration_desk.keeper is keeper
            assert served.warnings.onsite is run.onsite
            outbox = run.outbox
            wait_until(lambda: nodes.connected and outbox.figures()["connected"], "connected")
            # what no `except Exception` catches ends the nodes' paho thread and the outbox's
            # sender
            message, send = nodes._message, outbox._send

            def dies(*_: object) -> None:
                nodes._message = message
                raise SystemExit("gone")

            def sender_dies() -> None:
                outbox._send = send
                raise SystemExit("gone")

            nodes._message, outbox._send = dies, sender_dies
            pub = paho.Client(paho.CallbackAPIVersion.VERSION2, protocol=paho.MQTTv311)
            pub.connect("127.0.0.1", plan.mqtt.port)
            pub.loop_start()
            try:
                topic = Topics.of(plan.mqtt.topic_prefix, plan.mqtt.site).keypoints(cam)
                pub.publish(topic, b"{}", qos=1).wait_for_publish(5)
            finally:
                pub.loop_stop()
                pub.disconnect()
            outbox.wake()
            wait_until(
                lambda: nodes.restarts >= 1 and outbox.counts["restarts"] >= 1,
                "the watchdog started both receivers again",
            )
            wait_until(lambda: nodes.connected and outbox.health().ok, "both running again")
        finally:
            run.parts.close()
    assert run.parts.started == []
    assert served.calibration_desk.keeper is None and served.warnings.onsite is None
    # the outbox closed, then status.json written with what it sent
    assert "outbox" in json.loads(plan.status_path.read_text())
