"""Waiting in tests: for a condition, with a deadline (never a fixed sleep)."""

from __future__ import annotations

import time
import urllib.error
import urllib.request
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

import pytest

T = TypeVar("T")


def wait_until(
    condition: Callable[[], T], what: str, timeout_s: float = 20.0, poll_s: float = 0.01
) -> T:
    """Poll ``condition()`` until it is true; fail the test if ``timeout_s`` passes first.
    Returns the true value it gave (what was found, read at the moment it was found)."""
    deadline = time.monotonic() + timeout_s
    while not (found := condition()):
        if time.monotonic() > deadline:
            pytest.fail(f"still waiting for {what} after {timeout_s} s")
        time.sleep(poll_s)
    return found


def listening(port: int, taken: bool = False) -> bool:
    """Whether a socket listens on TCP ``port``, seen without connecting: ffmpeg ``-listen 1``
    takes the first client that connects as its only one, so a probe would use it up.

    taken: also true when the port holds an established connection, for a server such as
    ffmpeg ``-listen 1`` that stops listening once its one client came (a client that
    reconnects by itself can come between two looks)."""
    states = ("0A", "01") if taken else ("0A",)  # LISTEN, ESTABLISHED
    tables = [Path("/proc/net/tcp"), Path("/proc/net/tcp6")]
    if not tables[0].exists():
        pytest.skip("needs /proc/net/tcp to see that ffmpeg listens")
    for table in tables:
        rows = table.read_text().splitlines()[1:] if table.exists() else []
        for row in rows:
            local, state = row.split()[1], row.split()[3]
            if state in states and int(local.rsplit(":", 1)[1], 16) == port:
                return True
    return False


def http_get(url: str, timeout_s: float = 5.0) -> tuple[int, bytes]:
    """GET `url`: (status, body); (0, b"") when nothing answers (a probe for wait_until)."""
    try:
        with urllib.request.urlopen(url, timeout=timeout_s) as r:
            return r.status, r.read()
    except urllib.error.HTTPError as e:
        return e.code, e.read()
    except OSError:
        return 0, b""
