"""The one typed configuration schema; every default lives here, one module per part of the
system (config.processing: reconstruction and tracking; config.sources: cameras, nodes,
detector, input, outputs; config.service: serve, mqtt, control_room, storage; config.scada:
iec104, opcua), the machinery in config.fields.

A TOML file overrides any subset of it; unknown tables or keys are rejected with an error that
names the file and the key. Every numeric field carries its range beside its default
(`number(default, ge=..., le=...)`), checked whenever a section is built: from a file, in code,
or by `dataclasses.replace` / `with_overrides` for command-line options.
"""

from __future__ import annotations

import argparse
import dataclasses
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import TypeVar

from stereopose.checks import FPS_MAX, FPS_MIN, read_limited
from stereopose.config.fields import MODES, Mode, Section, _schema, from_dict, number
from stereopose.config.processing import (
    AssociationConfig,
    PlausibilityConfig,
    ReconstructionConfig,
    TrackingConfig,
    TriangulationConfig,
)
from stereopose.config.scada import Iec104Config, OpcuaConfig, OpcuaPolicy
from stereopose.config.service import ControlRoomConfig, MqttConfig, ServeConfig, StorageConfig
from stereopose.config.sources import (
    CameraSource,
    DetectorConfig,
    InputConfig,
    NodeConfig,
    OutputConfig,
)
from stereopose.errors import ConfigError

__all__ = [
    "MODES",
    "AssociationConfig",
    "CameraSource",
    "Config",
    "ConfigError",
    "ControlRoomConfig",
    "DetectorConfig",
    "Iec104Config",
    "InputConfig",
    "Mode",
    "MqttConfig",
    "NodeConfig",
    "OpcuaConfig",
    "OpcuaPolicy",
    "OutputConfig",
    "PlausibilityConfig",
    "ReconstructionConfig",
    "Section",
    "ServeConfig",
    "StorageConfig",
    "TrackingConfig",
    "TriangulationConfig",
    "check_options",
    "from_dict",
    "load_config",
    "number",
    "parse_toml",
    "read_toml",
    "with_overrides",
]

_T = TypeVar("_T", bound=Section)


@_schema("")
@dataclass(frozen=True)
class Config(Section):
    # time base when the input has none
    fps: float = number(25.0, ge=FPS_MIN, le=FPS_MAX)
    reconstruction: ReconstructionConfig = field(default_factory=ReconstructionConfig)
    tracking: TrackingConfig = field(default_factory=TrackingConfig)
    # what `stereopose run` reads and writes; paths are relative to the config file
    calibration: str | None = None
    site: str | None = None
    output: str = "out/run"
    cameras: tuple[CameraSource, ...] = ()
    nodes: tuple[NodeConfig, ...] = ()
    detector: DetectorConfig = field(default_factory=DetectorConfig)
    input: InputConfig = field(default_factory=InputConfig)
    outputs: OutputConfig = field(default_factory=OutputConfig)
    serve: ServeConfig = field(default_factory=ServeConfig)
    mqtt: MqttConfig = field(default_factory=MqttConfig)
    iec104: Iec104Config = field(default_factory=Iec104Config)
    opcua: OpcuaConfig = field(default_factory=OpcuaConfig)
    storage: StorageConfig = field(default_factory=StorageConfig)
    control_room: ControlRoomConfig = field(default_factory=ControlRoomConfig)


def read_toml(path: Path, what: str) -> dict[str, object]:
    """A TOML file's tables; a missing, unreadable, oversized or invalid file is a ConfigError
    naming it (`what`: what the file is, for the message)."""
    raw = read_limited(path, what, ConfigError)
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as e:
        raise ConfigError(f"{path}: cannot read {what}: {e}") from None
    return parse_toml(text, path)


def parse_toml(text: str, path: Path | str) -> dict[str, object]:
    """TOML text -> tables; any parse failure is a ConfigError naming `path`."""
    try:
        return tomllib.loads(text)
    except ValueError as e:  # TOMLDecodeError, or an integer of more than 4300 digits
        raise ConfigError(f"{path}: invalid TOML: {e}") from None
    except RecursionError:  # tomllib recurses once per level of nested arrays or tables
        raise ConfigError(f"{path}: invalid TOML: arrays or tables nested too deeply") from None


def load_config(path: str | Path | None = None) -> Config:
    """Defaults, overridden by the TOML file at `path` when given."""
    if path is None:
        return Config()
    path = Path(path)
    data = read_toml(path, "configuration file")
    try:
        return from_dict(Config, data, "")
    except ConfigError as e:
        raise ConfigError(f"{path}: {e}".replace(": : ", ": ")) from None


def _replace(obj: _T, values: dict[str, object], where: str) -> _T:
    try:
        return dataclasses.replace(obj, **values)
    except TypeError as e:  # an unknown field
        raise ConfigError(f"{where}: {e}") from None


def with_overrides(config: Config, **sections: dict[str, object]) -> Config:
    """A copy of `config` with fields of its sections replaced: `tracking`, or one of the
    reconstruction sections; the new values are checked as a file's would be.

    Example: with_overrides(cfg, triangulation={"mode": "pair"}, tracking={"enabled": False}).
    """
    if "tracking" in sections:
        tracking = _replace(config.tracking, sections.pop("tracking"), "tracking")
        config = dataclasses.replace(config, tracking=tracking)
    rec = config.reconstruction
    for name, values in sections.items():
        current = getattr(rec, name, None)
        if not isinstance(current, Section):
            raise ConfigError(f"reconstruction: no section {name!r}")
        rec = dataclasses.replace(
            rec, **{name: _replace(current, values, f"reconstruction.{name}")}
        )
    return dataclasses.replace(config, reconstruction=rec)


def check_options(args: argparse.Namespace, *sections: type) -> None:
    """Check command-line options against the ranges of the schema fields of the same name in
    `sections` (e.g. InputConfig: --fps, --max-frames); an error names the option."""
    for cls in sections:
        for name, (rng, _, _) in cls._ranges.items():
            value = getattr(args, name, None)
            if value is not None:
                rng.check(value, f"--{name.replace('_', '-')}")
