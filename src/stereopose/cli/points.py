"""`stereopose points CONFIG.toml`: the IEC 60870-5-104 points of a service, as CSV.

The table (ioa,type,meaning,source; stereopose.scada.points) is built from the configuration's
calibration (its cameras, in the configuration's order), its site file (zones and behaviour
rules) and [iec104] (commands), the same way `serve` builds the points it serves, for the SCADA
engineer who configures the master. Only the files are read: nothing is opened or started.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

from stereopose.cli.common import console, out
from stereopose.errors import ConfigError

if TYPE_CHECKING:
    from stereopose.config import Config
    from stereopose.scada.points import PointsTable


def _resolve(base: Path, value: str) -> Path:
    p = Path(value).expanduser()
    return p if p.is_absolute() else base / p


def points_of(config_path: Path) -> tuple[Config, PointsTable]:
    """The points table of the service configured at `config_path`; a ConfigError naming the
    file (the configuration, its calibration or its site) otherwise."""
    from stereopose.config import load_config
    from stereopose.fence import load_site
    from stereopose.pipeline.run import check_run_config, run_rig
    from stereopose.scada.points import points_table

    cfg = load_config(config_path)
    check_run_config(cfg, config_path)
    base = config_path.resolve().parent
    rig = run_rig(config_path, _resolve(base, cfg.calibration or ""), cfg)
    site = load_site(_resolve(base, cfg.site)) if cfg.site else None
    return cfg, points_table(site, rig, commands=cfg.iec104.commands)


def _points(args: argparse.Namespace) -> int:
    path = Path(args.config)
    if not path.exists():
        raise ConfigError(f"{path}: configuration file not found")
    cfg, table = points_of(path)
    if not cfg.iec104.enabled:
        console.print(
            f"note: [iec104] is not enabled in {path}: serve runs no outstation "
            "until `enabled = true`",
            markup=False,
            highlight=False,
            soft_wrap=True,
        )
    out.file.write(table.csv())
    out.file.flush()
    return 0
