"""Hostile inputs for the loaders: TOML text from any nested value, and Hypothesis strategies of
values that are wrong in type, size or range (NaN, infinities, giant integers, nesting)."""

from __future__ import annotations

import json
import math
from typing import Any

from hypothesis import strategies as st

# Numbers at and beyond the edges: zero, signs, subnormals, floats near overflow, integers
# beyond any float or beyond 64 bits.
EDGES: list[Any] = [
    0,
    -1,
    1,
    0.0,
    -0.0,
    1e-300,
    -1e-300,
    5e-324,
    1e308,
    -1e308,
    math.nan,
    math.inf,
    -math.inf,
    2**31,
    2**63,
    2**64 + 1,
    -(2**63) - 1,
    10**400,
    32,
    0.5,
    1.5,
    2,
    100000,
    1e6,
    1e12,
]

numbers = st.one_of(
    st.sampled_from(EDGES),
    st.floats(allow_nan=True, allow_infinity=True),
    st.integers(),
)
scalars = st.one_of(numbers, st.booleans(), st.text(max_size=12))
values = st.recursive(
    scalars,
    lambda children: (
        st.lists(children, max_size=4) | st.dictionaries(st.text(max_size=6), children, max_size=3)
    ),
    max_leaves=12,
)


def toml_value(v: Any) -> str:
    """Any nested value as TOML (tables inline), so that tomllib reads back the same value."""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v) if abs(v) < 10**4000 else "9" * 5000  # beyond Python's digit limit
    if isinstance(v, float):
        if math.isnan(v):
            return "nan"
        return repr(v) if math.isfinite(v) else ("inf" if v > 0 else "-inf")
    if isinstance(v, str):
        return toml_str(v)
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(toml_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{toml_str(k)} = {toml_value(x)}" for k, x in v.items()) + "}"
    raise TypeError(type(v))


def toml_str(s: str) -> str:
    return json.dumps(s, ensure_ascii=False).replace("\x7f", "\\u007f")


def toml_text(doc: dict[str, Any]) -> str:
    """A top-level table as TOML text."""
    return "".join(f"{toml_str(k)} = {toml_value(v)}\n" for k, v in doc.items())
