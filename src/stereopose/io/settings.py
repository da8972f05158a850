"""Small frozen settings of one output, checked at once against the ranges beside their
defaults; a bad value is a ConfigError naming its key as the configuration file will spell it
(``<section>.<key>``)."""

from __future__ import annotations

import dataclasses
from typing import Any

from stereopose.checks import Range

__all__ = ["check_settings", "ranged"]


def ranged(default: Any, **bounds: Any) -> Any:
    """A numeric settings field with its range (ge/gt/le/lt, integer; see checks.Range)."""
    return dataclasses.field(default=default, metadata={"range": Range(**bounds)})


def check_settings(settings: Any, section: str) -> None:
    """Check every ranged field of a frozen settings dataclass; floats stored as float."""
    for f in dataclasses.fields(settings):
        rng: Range | None = f.metadata.get("range")
        if rng is None:
            continue
        value = getattr(settings, f.name)
        rng.check(value, f"{section}.{f.name}")
        if not rng.integer:
            object.__setattr__(settings, f.name, float(value))
