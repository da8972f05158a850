"""Array checks at the boundary of the compiled loops: a caller gets an error naming the
argument and the expected and actual shapes, not a numba typing error."""

from __future__ import annotations

import numpy as np


def checked(
    a: object,
    name: str,
    shape: tuple[int | str | None, ...],
    dtype: type = np.float64,
    sizes: dict[str, int] | None = None,
) -> np.ndarray:
    """`a` as a C-contiguous array of `dtype`, checked against `shape`.

    shape: per axis an int (that size), None (any) or a name ("C", "G", ...): every axis of
    that name must have the same size, in this call and in the other calls sharing `sizes`.
    Raises ValueError such as "P must have shape (C, 3, 4), got (3, 4)".
    """
    arr = np.ascontiguousarray(a, dtype=dtype)
    ok = arr.ndim == len(shape)
    sizes = {} if sizes is None else sizes
    if ok:
        for n, want in zip(arr.shape, shape, strict=True):
            if isinstance(want, str):
                ok = sizes.setdefault(want, n) == n
            elif want is not None:
                ok = n == want
            if not ok:
                break
    if not ok:
        expected = ", ".join("*" if s is None else str(s) for s in shape)
        if len(shape) == 1:
            expected += ","
        raise ValueError(f"{name} must have shape ({expected}), got {arr.shape}")
    return arr


def checked_rows(rows: object, n: int, name: str = "rows") -> np.ndarray:
    """`rows` as C-contiguous int64 indices, checked to lie in [0, n): the compiled loops do
    not check their indices."""
    arr = checked(rows, name, (None,), dtype=np.int64)
    if arr.size and not (arr.min() >= 0 and arr.max() < n):
        raise IndexError(f"{name} must lie in [0, {n}), got {arr.min()}..{arr.max()}")
    return arr
