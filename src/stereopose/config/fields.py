"""The configuration schema's machinery: a section is a frozen dataclass over `Section`, marked
with its key path by `_schema`; each numeric field has its range (`number(default, ge=...,
le=...)`) checked whenever a section is built, and a value from a file is checked against its
field's type (`from_dict`)."""

from __future__ import annotations

import dataclasses
import types
from collections.abc import Callable
from dataclasses import field
from typing import (
    TYPE_CHECKING,
    Any,
    ClassVar,
    Literal,
    TypeVar,
    Union,
    cast,
    get_args,
    get_origin,
    get_type_hints,
)

if TYPE_CHECKING:
    from _typeshed import DataclassInstance

from stereopose.checks import Range
from stereopose.errors import ConfigError
from stereopose.secrets import shown

Mode = Literal["pair", "weighted", "robust"]
MODES: tuple[str, ...] = get_args(Mode)

_T = TypeVar("_T")
_LENGTH_M = 1000.0  # the largest distance a configuration may hold, metres


def number(default: Any, **bounds: Any) -> Any:
    """A numeric field with its range: ge/gt/le/lt bounds, integer, multiple_of (see Range)."""
    return field(default=default, metadata={"range": Range(**bounds)})


def _base(tp: Any) -> tuple[Any, bool]:
    """(type without None, whether None is allowed)."""
    if get_origin(tp) in (Union, types.UnionType):
        options = [a for a in get_args(tp) if a is not type(None)]
        return (options[0] if len(options) == 1 else tp), len(options) < len(get_args(tp))
    return tp, False


class Section:
    """A section of the schema: a frozen dataclass, made by `@_schema(key path)` over
    `@dataclass(frozen=True)`, whose fields are checked on every construction."""

    __dataclass_fields__: ClassVar[dict[str, dataclasses.Field[object]]]  # set by @dataclass
    _section: ClassVar[str] = ""
    _ranges: ClassVar[dict[str, tuple[Range, bool, bool]]] = {}
    _choices: ClassVar[dict[str, tuple[object, ...]]] = {}

    def __post_init__(self) -> None:
        _check_fields(self)


_S = TypeVar("_S", bound=Section)


def _schema(section: str) -> Callable[[type[_S]], type[_S]]:
    """The section of the schema at key path `section`: its numeric fields' ranges and its
    choices read from the dataclass; a numeric field without a range is refused when the class
    is defined."""

    def wrap(cls: type[_S]) -> type[_S]:
        if "__dataclass_fields__" not in cls.__dict__:
            raise TypeError(f"{cls.__name__}: @_schema goes over @dataclass(frozen=True)")
        hints = get_type_hints(cls)
        ranges, choices = {}, {}
        for f in dataclasses.fields(cast("type[DataclassInstance]", cls)):
            tp, optional = _base(hints[f.name])
            if tp in (int, float):
                if "range" not in f.metadata:
                    raise TypeError(f"{cls.__name__}.{f.name}: a number needs a range (number())")
                ranges[f.name] = (f.metadata["range"], optional, tp is float)
            elif get_origin(tp) is Literal:
                choices[f.name] = get_args(tp)
        cls._section, cls._ranges, cls._choices = section, ranges, choices
        return cls

    return wrap


def _check_fields(self: Section) -> None:
    cls = type(self)
    for name, allowed in cls._choices.items():
        value = getattr(self, name)
        if value not in allowed:
            raise ConfigError(f"{_key(cls, name)}: expected one of {list(allowed)}, got {value!r}")
    for name, (rng, optional, is_float) in cls._ranges.items():
        value = getattr(self, name)
        if value is None and optional:
            continue
        rng.check(value, _key(cls, name))
        if is_float and value is not None:
            object.__setattr__(self, name, float(value))
    check = getattr(cls, "_check", None)
    if check is not None:  # what a range cannot say (an address, a list that may not be empty)
        check(self)


def _key(cls: type[Section], name: str) -> str:
    return f"{cls._section}.{name}" if cls._section else name


def _check_value(value: object, tp: Any, where: str) -> Any:
    origin = get_origin(tp)
    if origin in (Union, types.UnionType):
        options = [a for a in get_args(tp) if a is not type(None)]
        return _check_value(value, options[0], where) if len(options) == 1 else value
    if origin is tuple:
        item = get_args(tp)[0]
        if not isinstance(value, list):
            raise ConfigError(f"{where}: expected a list, got {shown(where, value)}")
        if isinstance(item, type) and dataclasses.is_dataclass(item):
            return tuple(from_dict(item, v, f"{where}[{i}]") for i, v in enumerate(value))
        return tuple(_check_value(v, item, f"{where}[{i}]") for i, v in enumerate(value))
    if origin is Literal:
        if value not in get_args(tp):
            raise ConfigError(
                f"{where}: expected one of {list(get_args(tp))}, got {shown(where, value)}"
            )
        return value
    if tp is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{where}: expected true or false, got {shown(where, value)}")
        return value
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{where}: expected an integer, got {shown(where, value)}")
        return value
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"{where}: expected a number, got {shown(where, value)}")
        try:
            return float(value)
        except OverflowError:  # an integer beyond any float: its range check names it
            return value
    if tp is str:
        if not isinstance(value, str):
            raise ConfigError(f"{where}: expected a string, got {shown(where, value)}")
        return value
    return value


def from_dict(cls: type, data: object, where: str) -> Any:
    """Build dataclass `cls` from a (possibly partial) dict, rejecting unknown keys and values
    out of range."""
    if not isinstance(data, dict):
        raise ConfigError(f"{where}: expected a table, got {shown(where, data)}")
    hints = get_type_hints(cls)
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(data) - names)
    if unknown:
        raise ConfigError(
            f"{where}: unknown key(s) {', '.join(unknown)}; known: {', '.join(sorted(names))}"
        )
    kwargs: dict[str, object] = {}
    for key, value in data.items():
        tp = hints[key]
        sub = f"{where}.{key}" if where else key
        if isinstance(tp, type) and dataclasses.is_dataclass(tp):
            kwargs[key] = from_dict(tp, value, sub)
        else:
            kwargs[key] = _check_value(value, tp, sub)
    return cls(**kwargs)
