"""Ranges of the numbers read from files and options, checked once at the boundary.

A Range is an interval (open or closed at each end) of finite numbers, optionally of integers or
of multiples of a step. Every numeric field of the configuration schema carries one (see
`number` in config.fields); calibration and site files are checked against the bounds below.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from stereopose.errors import CalibrationError, ConfigError, StereoposeError

# Frame rates of the configuration, the site and the command line, frames per second.
FPS_MIN, FPS_MAX = 0.1, 1000.0
DAY_S = 86400.0  # the longest duration a configuration may hold
SITE_LIMIT_M = 1e4  # zone coordinates and height bands, metres from the world origin
MAX_ZONE_VERTICES = 1000
MAX_ZONES = 1000
# Calibration: far beyond any real camera, near enough that the arithmetic stays exact.
MAX_IMAGE_PX = 100_000.0
MAX_FOCAL_PX = 1e6
MAX_DISTORTION = 1e3  # |k1|, |k2|, |p1|, |p2|, |k3|
MAX_ROTATION_RAD = 100.0  # each Rodrigues component (any rotation has a vector of norm <= pi)
MAX_TRANSLATION_M = 1e4


@dataclass(frozen=True)
class Range:
    """Finite numbers within bounds: ge/gt below (closed/open), le/lt above; integer: whole
    numbers only (Python ints, not bools); multiple_of: integers that are multiples of it."""

    ge: float | None = None
    gt: float | None = None
    le: float | None = None
    lt: float | None = None
    integer: bool = False
    multiple_of: int | None = None

    def describe(self) -> str:
        """What a value must be, e.g. "a number in (0, 1]" or "an integer >= 1"."""
        if self.multiple_of:
            kind = f"a multiple of {self.multiple_of}"
        else:
            kind = "an integer" if self.integer else "a finite number"
        lo = self.ge if self.ge is not None else self.gt
        hi = self.le if self.le is not None else self.lt
        if lo is not None and hi is not None:
            left, right = "[" if self.ge is not None else "(", "]" if self.le is not None else ")"
            return f"{kind} in {left}{_fmt(lo)}, {_fmt(hi)}{right}"
        if lo is not None:
            return f"{kind} {'>=' if self.ge is not None else '>'} {_fmt(lo)}"
        if hi is not None:
            return f"{kind} {'<=' if self.le is not None else '<'} {_fmt(hi)}"
        return kind

    def contains(self, value: object) -> bool:
        """Whether value is a number (of the right kind) within the bounds."""
        if isinstance(value, (bool, np.bool_)):
            return False
        if self.integer or self.multiple_of:
            if not isinstance(value, numbers.Integral):
                return False
            if self.multiple_of and int(value) % self.multiple_of:
                return False
        elif not isinstance(value, numbers.Real):
            return False
        try:
            v = float(value)
        except OverflowError:  # an integer beyond any float
            return False
        return (
            math.isfinite(v)
            and (self.ge is None or v >= self.ge)
            and (self.gt is None or v > self.gt)
            and (self.le is None or v <= self.le)
            and (self.lt is None or v < self.lt)
        )

    def check(self, value: object, where: str, error: type[StereoposeError] = ConfigError) -> Any:
        """Return value when within range, else raise `error` naming `where` and the value."""
        if not self.contains(value):
            raise error(f"{where}: expected {self.describe()}, got {_show(value)}")
        return value


def _fmt(x: float) -> str:
    return str(int(x)) if float(x).is_integer() and abs(x) < 1e15 else f"{x:g}"


def _show(value: object) -> str:
    if isinstance(value, np.generic):
        value = value.item()
    text = repr(value)
    return text if len(text) <= 80 else text[:77] + "..."


FPS = Range(ge=FPS_MIN, le=FPS_MAX)
SITE_COORD = Range(ge=-SITE_LIMIT_M, le=SITE_LIMIT_M)
IMAGE_SIZE = Range(ge=1.0, le=MAX_IMAGE_PX)
_FOCAL = Range(gt=0.0, lt=MAX_FOCAL_PX)
_PIXEL = Range(gt=-MAX_FOCAL_PX, lt=MAX_FOCAL_PX)  # principal point and skew
_DISTORTION = Range(gt=-MAX_DISTORTION, lt=MAX_DISTORTION)
_ROTATION = Range(ge=-MAX_ROTATION_RAD, le=MAX_ROTATION_RAD)
_TRANSLATION = Range(gt=-MAX_TRANSLATION_M, lt=MAX_TRANSLATION_M)
_DIST_NAMES = ("k1", "k2", "p1", "p2", "k3")


def check_camera_numbers(
    size: np.ndarray,
    matrix: np.ndarray,
    distortions: np.ndarray,
    rvec: np.ndarray,
    translation: np.ndarray,
    owner: str,
) -> None:
    """Plausible bounds of a camera's parameters (size (2,) px, matrix (3, 3) px, distortions
    (4,) or (5,), rvec (3,) Rodrigues, translation (3,) m); CalibrationError names owner,
    the parameter and its value."""

    def check(rng: Range, value: float, what: str) -> None:
        rng.check(float(value), f"{owner}: {what}", CalibrationError)

    for v, what in zip(size, ("width", "height"), strict=True):
        check(IMAGE_SIZE, v, f"size {what} (px)")
    check(_FOCAL, matrix[0, 0], "fx (px)")
    check(_FOCAL, matrix[1, 1], "fy (px)")
    check(_PIXEL, matrix[0, 2], "cx (px)")
    check(_PIXEL, matrix[1, 2], "cy (px)")
    check(_PIXEL, matrix[0, 1], "skew (px)")
    for v, what in zip(distortions, _DIST_NAMES[: len(distortions)], strict=True):
        check(_DISTORTION, v, f"distortion {what}")
    for v, what in zip(rvec, ("rx", "ry", "rz"), strict=True):
        check(_ROTATION, v, f"rotation {what} (rad)")
    for v, what in zip(translation, ("tx", "ty", "tz"), strict=True):
        check(_TRANSLATION, v, f"translation {what} (m)")


MAX_FILE_BYTES = 16 * 1024 * 1024  # a configuration, site or calibration file beyond: refused


def read_limited(path: Path, what: str, error: type[StereoposeError]) -> bytes:
    """The bytes of the regular file at path, at most MAX_FILE_BYTES; missing, unreadable, not a
    regular file (a folder, a device) or larger: `error` naming the file (`what`: what it is)."""
    try:
        if path.exists() and not path.is_file():
            raise error(f"{path}: cannot read {what}: not a regular file")
        with path.open("rb") as f:
            raw = f.read(MAX_FILE_BYTES + 1)
    except FileNotFoundError:
        raise error(f"{path}: {what} not found") from None
    except OSError as e:
        raise error(f"{path}: cannot read {what}: {e.strerror or e}") from None
    if len(raw) > MAX_FILE_BYTES:
        raise error(f"{path}: {what} larger than {MAX_FILE_BYTES >> 20} MiB")
    return raw


def named_tables(
    items: list, section: str, what: str, lead: str = ""
) -> Iterator[tuple[str, dict]]:
    """Each (name, table) of a site file's `[[section]]` tables, in order: every item a table
    with a unique non-empty string `name`, else a ConfigError (prefixed by `lead`) naming the
    item, or the `what` by its name ("zone 'panel A': the name is used twice")."""
    seen: set[str] = set()
    for k, item in enumerate(items):
        if not isinstance(item, dict):
            raise ConfigError(f"{lead}{section}[{k}]: expected a table")
        name = item.get("name")
        if name is None:
            raise ConfigError(f"{lead}{section}[{k}]: missing `name`")
        if not isinstance(name, str) or not name:
            raise ConfigError(
                f"{lead}{section}[{k}]: name must be a non-empty string, got {name!r}"
            )
        if name in seen:
            raise ConfigError(f"{lead}{what} {name!r}: the name is used twice")
        seen.add(name)
        yield name, item
