"""`stereopose serve`: the always-on service, from a configuration or the real demo."""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path
from typing import TYPE_CHECKING

from stereopose.cli.common import console, out
from stereopose.errors import ConfigError, IncompleteOutputError, StereoposeError

if TYPE_CHECKING:
    from stereopose.site.plan import ServePlan


def _config_path(args: argparse.Namespace) -> Path:
    if args.demo:
        if args.config is not None:
            raise ConfigError("serve: give either CONFIG.toml or --demo, not both")
        from stereopose.pipeline.demo import write_serve_demo_config

        path = write_serve_demo_config(
            args.out, args.data, 8787 if args.port is None else args.port
        )
        out.print(
            "[bold]Serving the real demo[/]: Pose2Sim's 4 cameras looped (forward then backward), "
            f"its calibration and a demo site -> {path}",
            soft_wrap=True,
        )
        return path
    if args.config is None:
        raise ConfigError("serve: give the service's CONFIG.toml, or --demo")
    if args.data is not None:
        raise ConfigError("serve: --data goes with --demo (a configuration names its `output`)")
    if not Path(args.config).exists():
        raise ConfigError(f"{args.config}: configuration file not found")
    return Path(args.config)


def _plan(path: Path, port: int | None) -> ServePlan:
    from stereopose.config import ServeConfig, load_config
    from stereopose.site.plan import plan_serve

    cfg = load_config(path)
    if port is not None:
        ServeConfig._ranges["port"][0].check(port, "--port")
        cfg = dataclasses.replace(cfg, serve=dataclasses.replace(cfg.serve, port=port))
    return plan_serve(path, cfg)


def _console_line(url: str, config: Path, out_dir: Path) -> str:
    """Where the operator console is, and how to add its first user when it has none."""
    from stereopose.web.users import UserStore

    line = f"operator console: {url}/"
    try:
        none = UserStore.in_folder(out_dir).count() == 0
    except StereoposeError as e:
        return f"{line} (its users cannot be read: {e})"
    if none:
        line += (
            f"; no user yet: add one with `stereopose users add NAME --role admin "
            f"--config {config}` (the password is read from standard input)"
        )
    return line


def _serve(args: argparse.Namespace) -> int:
    path = _config_path(args)
    plan = _plan(path, args.port)
    from stereopose.site.plan import interfaces
    from stereopose.site.serve import serve

    def ready(url: str) -> None:
        out.print(
            f"serving: health {url}/api/health, metrics {url}/metrics; outputs in "
            f"{plan.out_dir}; stop with Ctrl-C or SIGTERM",
            highlight=False,
            soft_wrap=True,
        )
        out.print(_console_line(url, path, plan.out_dir), highlight=False, soft_wrap=True)
        shown = ", ".join(interfaces(plan.config, plan.site))
        out.print(f"interfaces: {shown}", highlight=False, soft_wrap=True)

    try:
        result = serve(path, plan=plan, on_ready=ready)
    except KeyboardInterrupt:  # stopped while the cameras were opened: everything is closed
        console.print("stopped")
        return 0
    out.print(
        f"stopped after {result.summary.steps} steps; outputs in {plan.out_dir}",
        highlight=False,
        soft_wrap=True,
    )
    if result.failed:
        raise IncompleteOutputError(result.failed, result.outputs, result.summary)
    return 0
