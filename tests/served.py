"""Helpers of the service tests: a settable clock, frames to feed a ServiceState, a server."""

from __future__ import annotations

import contextlib
import json
import sqlite3
import urllib.error
import urllib.request
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from stereopose.io.sinks import FrameResult
from stereopose.site.health.state import ServiceState
from stereopose.site.http.app import create_app
from stereopose.types import Event, People3D
from stereopose.web.server import Server, ServeSettings


class Clock:
    """A clock the test moves by hand (seconds)."""

    def __init__(self, now: float = 1000.0) -> None:
        self.now = now

    def __call__(self) -> float:
        return self.now


def frame_result(frame: int, people: int) -> FrameResult:
    """A frame with `people` people (joints at the origin) and no 2D input."""
    joints = np.zeros((people, 17, 3))
    people3d = People3D(
        frame=frame,
        joints=joints,
        conf=np.ones((people, 17)),
        ids=np.arange(people),
        reprojection_px=np.zeros((people, 17)),
        views=np.full((people, 17), 2),
        detections=np.zeros((people, 2), dtype=int),
    )
    return FrameResult(frame, frame / 25.0, {}, people3d)


def event(kind: str = "enter", frame: int = 1) -> Event:
    return Event(
        t=frame / 25.0,
        frame=frame,
        person=1,
        zone="panel_A",
        kind="energized",
        type=kind,
        onset_t=frame / 25.0,
    )


@contextmanager
def serving(state: ServiceState, **server_kw: object) -> Iterator[Server]:
    """A real uvicorn server over create_app(state) on a free 127.0.0.1 port."""
    server = Server(create_app(state), ServeSettings(port=0), **server_kw)
    server.start()
    try:
        yield server
    finally:
        assert server.stop(), "the server thread did not end"


def get(url: str, method: str = "GET", data: bytes | None = None, headers=None):
    """(status, headers, body bytes) of one request; HTTP errors are answers too."""
    req = urllib.request.Request(url, data=data, method=method, headers=headers or {})
    try:
        with urllib.request.urlopen(req, timeout=10) as r:
            return r.status, r.headers, r.read()
    except urllib.error.HTTPError as e:
        with e:
            return e.code, e.headers, e.read()


def get_json(url: str) -> tuple[int, dict]:
    status, _, body = get(url)
    return status, json.loads(body)


def log_rows(db: Path, sql: str) -> list[tuple]:
    """Rows of an event log, read as another process would (read-only, no lock held); none
    before the file or its tables are made."""
    if not db.exists():
        return []
    try:
        with contextlib.closing(sqlite3.connect(f"file:{db}?mode=ro", uri=True, timeout=5)) as c:
            return c.execute(sql).fetchall()
    except sqlite3.OperationalError:  # the tables not made yet
        return []
