"""`stereopose control-room CONFIG.toml`: many sites' events in one store, over the central
broker."""

from __future__ import annotations

import argparse

from stereopose.cli.common import out


def _control_room(args: argparse.Namespace) -> int:
    from stereopose.controlroom.service import run_control_room

    def ready(url: str, plan) -> None:
        from stereopose.controlroom.store import shown_database

        out.print(
            f"control room: {url}/api/sites, health {url}/api/health, metrics "
            f"{url}/metrics; store {shown_database(plan.database)}; broker {plan.mqtt.host}:"
            f"{plan.mqtt.port}; stop with Ctrl-C or SIGTERM",
            highlight=False,
            soft_wrap=True,
        )

    run_control_room(args.config, on_ready=ready)
    out.print("control room stopped", highlight=False)
    return 0
