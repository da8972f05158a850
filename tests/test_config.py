"""The configuration schema: defaults, overrides, unknown keys and wrong types."""

from __future__ import annotations

from pathlib import Path

import pytest

from stereopose.config import Config, load_config, with_overrides
from stereopose.errors import ConfigError


def test_defaults_without_a_file() -> None:
    cfg = load_config(None)
    assert cfg == Config()
    assert cfg.reconstruction.triangulation.mode == "robust"


def test_partial_override(tmp_path: Path) -> None:
    f = tmp_path / "c.toml"
    f.write_text("fps = 30\n[reconstruction.triangulation]\nmode = 'pair'\npair_a = 0.02\n")
    cfg = load_config(f)
    assert cfg.fps == 30.0
    assert cfg.reconstruction.triangulation.mode == "pair"
    assert cfg.reconstruction.triangulation.pair_a == 0.02
    assert cfg.reconstruction.association == Config().reconstruction.association


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("[reconstruction.triangulation]\nmodee = 'pair'\n", r"c\.toml.*unknown key.*modee"),
        ("[reconstruction.triangulation]\nmode = 'best'\n", r"mode: expected one of"),
        ("[reconstruction.association]\nmin_common_joints = 2.5\n", r"expected an integer"),
        ("fps = 'fast'\n", r"fps: expected a number"),
        ("[reconstruction]\nassociation = 3\n", r"association: expected a table"),
        ("[nonsense]\n", r"unknown key.*nonsense"),
        ("fps = \n", r"invalid TOML"),
    ],
)
def test_bad_files_name_the_key(tmp_path: Path, text: str, message: str) -> None:
    f = tmp_path / "c.toml"
    f.write_text(text)
    with pytest.raises(ConfigError, match=message):
        load_config(f)


def test_missing_file(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="not found"):
        load_config(tmp_path / "none.toml")


def test_with_overrides() -> None:
    cfg = with_overrides(Config(), triangulation={"mode": "weighted"})
    assert cfg.reconstruction.triangulation.mode == "weighted"
