"""GET /api/clips/{file}: an event clip, with Range requests (the page's video element seeks).

GET /api/clips/{file}/play: the same clip played as Motion JPEG (multipart/x-mixed-replace, at
the clip's frame rate, ending with its last frame), which an <img> shows in any browser: the
drawn clips are MPEG-4 Part 2, which browsers' video elements do not decode (this OpenCV has
no H.264 encoder, and a VP9 one far too slow for clips written as the alarms come). At most
PLAYERS at once and PLAYERS_PER_USER of one user (site.http.places: a user's newer player ends
their own oldest; 503 with Retry-After when the others' hold every place), each frame decoded
and JPEG-encoded as it is sent. A player's place comes back as soon as its answer ends: at the
clip's end, when its client leaves (seen within a frame), or when it is ended for a newer one.

Only a finished clip directly in the output folder's clips/ is served: the name is one path
part of letters, digits, '_', '.', '-' ending in .mp4 (not .part.mp4), not starting with a dot,
and the file a regular file there (a symbolic link is refused); anything else is 404 (400 for a
name that cannot be one).
"""

from __future__ import annotations

import os
import re
import stat
import threading
import time
import weakref
from collections.abc import Mapping
from pathlib import Path

import cv2
from fastapi import APIRouter, Depends, HTTPException
from fastapi.responses import FileResponse, StreamingResponse
from starlette.types import Receive, Scope, Send

from stereopose.io.sinks.clips import CLIP_SUFFIX, PART_SUFFIX
from stereopose.site.http.places import FairPlaces, Place
from stereopose.site.http.web import Console
from stereopose.web.auth import Viewer, console_parts

router = APIRouter(tags=["events"])

_NAME = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.-]{0,250}")


PLAYERS = 4  # clips played as Motion JPEG at once
PLAYERS_PER_USER = 2
players = FairPlaces(PLAYERS, per_user=PLAYERS_PER_USER)  # no places reserved: nobody's alarms
_BOUNDARY = "clipframe"


def _clip_path(file: str, parts: Console) -> tuple[Path, os.stat_result]:
    """The clip's path and its stat, or the HTTPException that refuses it."""
    if not _NAME.fullmatch(file) or ".." in file or not file.endswith(CLIP_SUFFIX):
        raise HTTPException(400, "not a clip name")
    if file.endswith(PART_SUFFIX) or parts.clips_dir is None:
        raise HTTPException(404, "no such clip")
    path = parts.clips_dir / file
    try:
        st = os.lstat(path)
    except OSError:
        raise HTTPException(404, "no such clip") from None
    if not stat.S_ISREG(st.st_mode) or os.path.dirname(os.path.realpath(path)) != os.path.realpath(
        parts.clips_dir
    ):
        raise HTTPException(404, "no such clip")
    return path, st


@router.get(
    "/api/clips/{file}",
    response_class=FileResponse,
    responses={200: {"content": {"video/mp4": {}}}, 400: {}, 404: {}},
)
def clip(file: str, session: Viewer, parts: Console = Depends(console_parts)) -> FileResponse:  # noqa: B008
    """The clip (video/mp4)."""
    path, st = _clip_path(file, parts)
    return FileResponse(
        path,
        media_type="video/mp4",
        stat_result=st,
        headers={"Cache-Control": "private, max-age=3600"},
    )


@router.get(
    "/api/clips/{file}/play",
    response_class=StreamingResponse,
    responses={
        200: {"content": {f"multipart/x-mixed-replace; boundary={_BOUNDARY}": {}}},
        400: {},
        404: {},
        503: {},
    },
)
def play(file: str, session: Viewer, parts: Console = Depends(console_parts)) -> StreamingResponse:  # noqa: B008
    """The clip played as Motion JPEG at its frame rate, for an <img> (any browser)."""
    path, _ = _clip_path(file, parts)
    place = players.take(session.username, privileged=False)
    if place is None:
        raise HTTPException(
            503,
            f"{PLAYERS} clips are playing; try again when one ends",
            headers={"Retry-After": "5"},
        )
    player = _Player(path, place)  # gives its place back when it ends, is closed or dropped
    if not player.opened:
        player.close()
        raise HTTPException(404, "the clip cannot be read")
    kind = f"multipart/x-mixed-replace; boundary={_BOUNDARY}"
    return _PlayerResponse(player, media_type=kind, headers={"Cache-Control": "no-store"})


class _PlayerResponse(StreamingResponse):
    """The player's answer: closes the player (its place given back) as soon as the answer
    is over, however it ends (the clip's end, the client gone, the server stopping), not
    when the garbage collector gets to it."""

    def __init__(self, player: _Player, media_type: str, headers: Mapping[str, str]) -> None:
        super().__init__(player, media_type=media_type, headers=headers)
        self.player = player

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        try:
            await super().__call__(scope, receive, send)
        finally:
            self.player.close()


class _Player:
    """The clip's frames as JPEG parts, paced at its frame rate (iterated in the server's
    thread pool). It stops at the clip's end and when its place is ended for a newer player
    of its user; its place is given back once, at close() or when it is dropped."""

    def __init__(self, path: Path, place: Place) -> None:
        self._cap = cv2.VideoCapture(str(path), cv2.CAP_FFMPEG)
        self.place = place
        self.opened = self._cap.isOpened()
        fps = self._cap.get(cv2.CAP_PROP_FPS) if self.opened else 0.0
        self._step = 1.0 / fps if 0.1 <= fps <= 1000 else 0.1
        self._next_at = time.monotonic()
        self._lock = threading.Lock()  # the decoder is used by one thread at a time
        self._done = weakref.finalize(self, _finish, self._cap, place)

    def __iter__(self) -> _Player:
        return self

    def __next__(self) -> bytes:
        while self.place.ended is None:
            with self._lock:
                if not self._done.alive:
                    break
                ok, image = self._cap.read()
                if not ok:
                    break
                ok, jpeg = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, 80])
            if not ok:
                continue
            time.sleep(max(0.0, self._next_at - time.monotonic()))
            self._next_at += self._step
            data = jpeg.tobytes()
            head = f"--{_BOUNDARY}\r\nContent-Type: image/jpeg\r\nContent-Length: {len(data)}"
            return head.encode() + b"\r\n\r\n" + data + b"\r\n"
        self.close()
        raise StopIteration

    def close(self) -> None:
        players.give_back(self.place)  # at once, whatever the decoder is doing
        with self._lock:
            self._done()


def _finish(cap: cv2.VideoCapture, place: Place) -> None:
    cap.release()
    players.give_back(place)
