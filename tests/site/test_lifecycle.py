"""The service's parts as one ordered list: started in order, closed in the mirror order, the
parts started before one that fails still closed, one that fails to close never keeping the
others open."""

from __future__ import annotations

import logging

import pytest

from stereopose.site.lifecycle import Part, Parts, running


def _parts(log: list[str], names: str, fail_start: str = "", fail_close: str = "") -> Parts:
    def start(n: str) -> None:
        if n == fail_start:
            raise RuntimeError(f"{n} cannot start")
        log.append(f"start {n}")

    def close(n: str) -> None:
        log.append(f"close {n}")
        if n == fail_close:
            raise RuntimeError(f"{n} cannot close")

    return Parts([Part(n, lambda n=n: start(n), lambda n=n: close(n)) for n in names])


def test_parts_start_in_order_and_close_in_the_mirror_once() -> None:
    log: list[str] = []
    parts = _parts(log, "abc")
    assert parts.started == []
    parts.start()
    assert parts.started == ["a", "b", "c"]
    parts.close()
    parts.close()  # once
    assert log == ["start a", "start b", "start c", "close c", "close b", "close a"]
    assert parts.started == []


def test_a_part_that_cannot_start_leaves_those_before_it_to_close() -> None:
    log: list[str] = []
    parts = _parts(log, "abc", fail_start="b")
    with pytest.raises(RuntimeError, match="b cannot start"):
        parts.start()
    assert parts.started == ["a"]
    parts.close()
    assert log == ["start a", "close a"]


def test_a_part_that_cannot_close_is_logged_and_the_others_close(caplog) -> None:
    log: list[str] = []
    parts = _parts(log, "abc", fail_close="b")
    parts.start()
    with caplog.at_level(logging.WARNING):
        parts.close()
    assert log[3:] == ["close c", "close b", "close a"]
    assert "closing b: b cannot close" in caplog.text


def test_the_list_is_fixed_when_made() -> None:
    closed: list[str] = []
    parts = Parts([running("x", lambda: closed.append("x"))])
    assert isinstance(parts.order, tuple)
    with pytest.raises(AttributeError):
        parts.order[0].name = "y"  # type: ignore[misc]  # a Part is frozen
    with pytest.raises(ValueError, match="named twice"):
        Parts([running("x", print), running("x", print)])
    parts.start()
    with pytest.raises(RuntimeError, match="started already"):
        parts.start()
    parts.close()
    assert closed == ["x"]
