"""docs/architecture.md names every package and top-level module in its layout, so that the
one map of the code does not fall behind it."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "src" / "stereopose"
DOC = ROOT / "docs" / "architecture.md"


def layout_block(text: str) -> str:
    """The code block under `## The layout`."""
    section = text.split("## The layout", 1)[1]
    return section.split("```", 2)[1]


def missing_from(block: str, package: Path) -> list[str]:
    """The sub-packages (`name/`) and top-level modules (`name.py`) of `package` that `block`
    does not name."""
    named = set(re.findall(r"\b([a-z_][a-z0-9_]*(?:/|\.py))", block))
    parts = [f"{p.name}/" for p in package.iterdir() if p.is_dir() and (p / "__init__.py").exists()]
    parts += [f"{p.name}/" for p in package.iterdir() if p.is_dir() and p.name == "data"]
    parts += [p.name for p in package.glob("*.py") if p.name not in ("__init__.py", "__main__.py")]
    return sorted(set(parts) - named)


def test_every_package_and_module_is_in_the_architecture() -> None:
    missing = missing_from(layout_block(DOC.read_text(encoding="utf-8")), PACKAGE)
    assert not missing, f"docs/architecture.md's layout does not name: {', '.join(missing)}"


def test_a_missing_package_is_found(tmp_path: Path) -> None:
    for name in ("zones", "fence"):
        (tmp_path / name).mkdir()
        (tmp_path / name / "__init__.py").write_text("")
    (tmp_path / "checks.py").write_text("")
    (tmp_path / "__pycache__").mkdir()
    block = "src/stereopose/\n  fence/   the site file\n  checks.py  ranges\n"
    assert missing_from(block, tmp_path) == ["zones/"]
    assert missing_from(block + "  zones/  the zones\n", tmp_path) == []
