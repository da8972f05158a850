"""Every number of the configuration schema has a range, checked on every construction path;
whatever a configuration file holds, loading it raises ConfigError or gives values in range."""

from __future__ import annotations

import argparse
import dataclasses
import math
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, get_type_hints

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hostile import numbers, toml_text, values
from stereopose.checks import Range
from stereopose.config import (
    CameraSource,
    Config,
    DetectorConfig,
    InputConfig,
    Section,
    _schema,
    check_options,
    load_config,
    number,
    with_overrides,
)
from stereopose.errors import ConfigError

FUZZ = settings(
    max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)


def sections(cls: type = Config, path: str = "") -> Iterator[tuple[str, type]]:
    """(key path, class) of every section of the schema, the root included."""
    yield path, cls
    for f in dataclasses.fields(cls):
        default = f.default_factory() if f.default_factory is not dataclasses.MISSING else None
        if dataclasses.is_dataclass(default):
            yield from sections(type(default), f"{path}.{f.name}" if path else f.name)


def ranged_fields() -> list[tuple[str, str, type, Range]]:
    """(section path, field, class, range) of every numeric field."""
    return [
        (path, name, cls, rng)
        for path, cls in sections()
        for name, (rng, _, _) in cls._ranges.items()
    ]


def outside(rng: Range) -> list[Any]:
    """The nearest values beyond each bound, plus NaN, infinities and a boolean."""
    bad: list[Any] = [math.nan, math.inf, -math.inf, True]
    whole = rng.integer or rng.multiple_of
    for bound, down, closed in (
        (rng.ge, True, True),
        (rng.gt, True, False),
        (rng.le, False, True),
        (rng.lt, False, False),
    ):
        if bound is None:
            continue
        if whole:
            bad.append(int(bound) - 1 if down else int(bound) + 1)
        else:
            bad.append(math.nextafter(bound, -math.inf if down else math.inf) if closed else bound)
    if rng.multiple_of:
        bad.append(rng.multiple_of * 3 + 1)
    if rng.integer:
        bad.append(2.5)
    return bad


def config_file(tmp_path: Path, section: str, key: str, value: Any) -> Path:
    doc: dict[str, Any] = {key: value}
    for part in reversed(section.split(".") if section else []):
        doc = {part: doc}
    path = tmp_path / "c.toml"
    path.write_text(toml_text(doc), encoding="utf-8")
    return path


def test_every_number_has_a_range_and_its_default_is_in_it() -> None:
    found = ranged_fields()
    numeric = {
        (path, name)
        for path, cls in sections()
        for name, tp in get_type_hints(cls).items()
        if tp in (int, float, int | None, float | None)
    }
    assert {(p, n) for p, n, _, _ in found} == numeric and len(numeric) > 30
    for path, name, cls, rng in found:
        default = getattr(cls(), name)
        assert default is None or rng.contains(default), (path, name, default)
    for path, cls in sections():
        assert cls._section == path  # error messages name the key where the file has it


def test_a_number_without_a_range_is_refused_when_the_class_is_defined() -> None:
    with pytest.raises(TypeError, match="needs a range"):

        @_schema("x")
        @dataclass(frozen=True)
        class Bad(Section):
            n: int = 3

    with pytest.raises(TypeError, match="goes over @dataclass"):

        @_schema("x")
        class NotOne(Section):
            n: int = number(3, integer=True, ge=1)

    @_schema("x")
    @dataclass(frozen=True)
    class Good(Section):
        n: int = number(3, integer=True, ge=1)

    assert Good().n == 3


@pytest.mark.parametrize(
    ("path", "name", "cls", "rng"),
    ranged_fields(),
    ids=[f"{p}.{n}".lstrip(".") for p, n, _, _ in ranged_fields()],
)
def test_values_outside_each_range_name_file_key_and_value(tmp_path, path, name, cls, rng):
    key = f"{path}.{name}" if path else name
    for value in outside(rng):
        f = config_file(tmp_path, path, name, value)
        with pytest.raises(ConfigError) as e:
            load_config(f)
        is_float = cls._ranges[name][2]
        shown = repr(float(value)) if is_float and not isinstance(value, bool) else repr(value)
        assert str(e.value).startswith(f"{f}: {key}: expected"), str(e.value)
        assert str(e.value).endswith(f"got {shown}"), str(e.value)
    # the bounds themselves are inside (closed ends)
    for bound in (rng.ge, rng.le):
        if bound is not None:
            v = int(bound) if rng.integer or rng.multiple_of else float(bound)
            loaded = load_config(config_file(tmp_path, path, name, v))
            section = loaded
            for part in path.split(".") if path else []:
                section = getattr(section, part)
            assert getattr(section, name) == v


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("fps = nan\n", r"fps: expected a finite number in \[0.1, 1000\], got nan"),
        ("fps = 0\n", r"fps: expected .*, got 0"),
        ("fps = -5\n", r"fps: expected .*, got -5"),
        ("[tracking]\nbridge_s = nan\n", r"tracking.bridge_s: expected .*got nan"),
        ("[tracking]\nmax_lost_s = -1\n", r"tracking.max_lost_s: expected .*got -1"),
        (
            "[reconstruction.plausibility]\nmin_view_fraction = 2\n",
            r"reconstruction.plausibility.min_view_fraction: expected .* \[0, 1\], got 2",
        ),
        ("[input]\nfps = 0\n", r"input.fps: expected .*got 0"),
        ("[input]\nmax_frames = -1\n", r"input.max_frames: expected an integer >= 1, got -1"),
        ("[detector]\nimgsz = 600\n", r"detector.imgsz: expected a multiple of 32 .*got 600"),
        ("[detector]\nthreads = 0\n", r"detector.threads: expected an integer .*got 0"),
        ("[outputs]\noverlay_scale = 1.5\n", r"outputs.overlay_scale: .* \(0, 1\], got 1.5"),
        ("[tracking]\nconfirm_frames = " + "9" * 30 + "\n", r"confirm_frames: .*got 9999"),
        ("fps = " + "9" * 400 + "\n", r"fps: expected a finite number .*got 9999"),
        ("a = " + "9" * 5000 + "\n", r"invalid TOML"),
        ("a = " + "[" * 3000 + "]" * 3000 + "\n", r"invalid TOML: .*nested too deeply"),
    ],
)
def test_the_faults_found_are_errors(tmp_path: Path, text: str, message: str) -> None:
    f = tmp_path / "c.toml"
    f.write_text(text)
    with pytest.raises(ConfigError, match=message) as e:
        load_config(f)
    assert str(e.value).startswith(str(f))


def test_unreadable_files_are_errors(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="not a regular file"):
        load_config(tmp_path)
    big = tmp_path / "big.toml"
    big.write_bytes(b"# " + b"x" * (17 * 2**20))
    with pytest.raises(ConfigError, match="larger than 16 MiB"):
        load_config(big)
    latin = tmp_path / "latin.toml"
    latin.write_bytes(b'output = "\xff"\n')
    with pytest.raises(ConfigError, match="cannot read"):
        load_config(latin)


def test_every_construction_path_is_checked() -> None:
    with pytest.raises(ConfigError, match=r"^fps: expected .*got nan"):
        dataclasses.replace(Config(), fps=math.nan)
    with pytest.raises(ConfigError, match=r"^tracking.bridge_s: .*got -0.5"):
        with_overrides(Config(), tracking={"bridge_s": -0.5})
    with pytest.raises(ConfigError, match=r"triangulation.mode: expected one of .*'best'"):
        with_overrides(Config(), triangulation={"mode": "best"})
    with pytest.raises(ConfigError, match=r"tracking: .*nonsense"):
        with_overrides(Config(), tracking={"nonsense": 1})
    with pytest.raises(ConfigError, match=r"^input.max_frames: expected an integer >= 1, got 0"):
        InputConfig(max_frames=0)
    with pytest.raises(ConfigError, match=r"^detector.conf: .*\[0, 1\], got 2"):
        DetectorConfig(conf=2)
    assert Config(fps=30).fps == 30.0 and isinstance(Config(fps=30).fps, float)


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({"fps": -5.0}, r"^--fps: expected a finite number in \[0.1, 1000\], got -5.0"),
        ({"fps": math.nan}, r"^--fps: .*got nan"),
        ({"max_frames": 0}, r"^--max-frames: expected an integer >= 1, got 0"),
        ({"imgsz": 100}, r"^--imgsz: expected a multiple of 32"),
        ({"threads": 0}, r"^--threads: "),
        ({"iou": 1.5}, r"^--iou: "),
    ],
)
def test_command_line_options_are_checked_against_the_same_ranges(options, message) -> None:
    args = argparse.Namespace(fps=None, max_frames=None, imgsz=640, conf=0.25, iou=0.7)
    check_options(args, InputConfig, DetectorConfig)  # the defaults pass
    vars(args).update(options)
    with pytest.raises(ConfigError, match=message):
        check_options(args, InputConfig, DetectorConfig)


def inside(rng: Range) -> st.SearchStrategy:
    """Numbers within the range (the property below then checks what loads, too)."""
    lo = rng.ge if rng.ge is not None else rng.gt
    hi = rng.le if rng.le is not None else rng.lt
    if rng.integer or rng.multiple_of:
        step = rng.multiple_of or 1
        top = int(hi) // step if hi is not None else 10**6
        return st.integers(-(-int(lo) // step), top).map(lambda k: k * step)
    return st.floats(lo, hi, exclude_min=rng.gt is not None, exclude_max=rng.lt is not None)


@st.composite
def valid_dicts(draw, cls: type = Config) -> dict[str, Any]:
    """Tables shaped like the schema with values of the right type and range (any subset)."""
    hints = get_type_hints(cls)
    out: dict[str, Any] = {}
    for f in dataclasses.fields(cls):
        if not draw(st.booleans()):
            continue
        tp = hints[f.name]
        if f.name in cls._ranges:
            out[f.name] = draw(inside(cls._ranges[f.name][0]))
        elif f.name in cls._choices:
            out[f.name] = draw(st.sampled_from(cls._choices[f.name]))
        elif dataclasses.is_dataclass(tp):
            out[f.name] = draw(valid_dicts(tp))
        elif f.name == "cameras":
            out[f.name] = draw(st.lists(valid_dicts(CameraSource), max_size=2))
        elif tp is bool:
            out[f.name] = draw(st.booleans())
        else:
            out[f.name] = draw(st.text(max_size=8))
    return out


def _tables(doc: dict[str, Any], path: tuple[str, ...] = ()) -> list[tuple[str, ...]]:
    out = [path]
    for k, v in doc.items():
        if isinstance(v, dict):
            out += _tables(v, (*path, k))
    return out


@st.composite
def schema_dicts(draw) -> dict[str, Any]:
    """A valid schema-shaped table, often with one hostile value put in at any key (a known
    or an unknown one): wrong types, NaN, infinities, giant or edge numbers, nesting."""
    doc = draw(valid_dicts())
    if draw(st.integers(0, 3)) == 0:
        return doc
    table = doc
    for k in draw(st.sampled_from(_tables(doc))):
        table = table[k]
    known = sorted(table) or ["fps"]
    key = draw(st.sampled_from(known) | st.text(min_size=1, max_size=5))
    table[key] = draw(numbers | values)
    return doc


def _assert_in_range(cfg: Any) -> None:
    for name, (rng, optional, _) in type(cfg)._ranges.items():
        v = getattr(cfg, name)
        assert (v is None and optional) or rng.contains(v), (name, v)
    for f in dataclasses.fields(cfg):
        if dataclasses.is_dataclass(getattr(cfg, f.name)):
            _assert_in_range(getattr(cfg, f.name))


@FUZZ
@given(doc=schema_dicts())
def test_schema_shaped_files_load_in_range_or_raise_config_error(tmp_path, doc) -> None:
    f = tmp_path / "c.toml"
    f.write_text(toml_text(doc), encoding="utf-8")
    try:
        cfg = load_config(f)
    except ConfigError as e:
        assert str(e).startswith(f"{f}: ")
    else:
        _assert_in_range(cfg)


@FUZZ
@given(raw=st.binary(max_size=300) | st.sampled_from([b"fps = ", b"[a]\n[a]\n", b"\xef\xbb\xbf"]))
def test_arbitrary_bytes_raise_config_error_only(tmp_path, raw: bytes) -> None:
    f = tmp_path / "c.toml"
    f.write_bytes(raw)
    try:
        load_config(f)
    except ConfigError as e:
        assert str(e).startswith(f"{f}: ")
