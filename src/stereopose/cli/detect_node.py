"""`stereopose detect-node CONFIG.toml --cameras A,B`: a detection node of a site."""

from __future__ import annotations

import argparse
import signal
import threading

from stereopose.cli.common import out


def _detect_node(args: argparse.Namespace) -> int:
    from stereopose.nodes.node import DetectNode, plan_node

    cameras = [c.strip() for c in args.cameras.split(",") if c.strip()] if args.cameras else None
    plan = plan_node(args.config, cameras, node=args.node, name=args.name)
    node = DetectNode(plan)  # the model loaded before the broker is told the node is up
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    out.print(
        f"detection node {plan.name}: cameras {', '.join(plan.rig.names)} -> "
        f"{plan.mqtt.host}:{plan.mqtt.port} {node.topics.base}/keypoints/; stop with "
        "Ctrl-C or SIGTERM",
        highlight=False,
        soft_wrap=True,
    )
    figures = node.run(stop)
    pub = node.publisher
    sent = pub.counts.published if pub is not None else 0
    dropped = pub.counts.dropped if pub is not None else 0
    out.print(
        f"node {plan.name} stopped after {figures.steps} steps; {sent} messages sent, "
        f"{dropped} dropped",
        highlight=False,
        soft_wrap=True,
    )
    return 0
