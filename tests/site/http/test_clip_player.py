"""GET /api/clips/{file}/play: a drawn clip (MPEG-4 Part 2, which browsers' video elements do
not decode) played as Motion JPEG for an <img>: every frame a JPEG part, behind the login, the
same names refused as for the file itself, and at most PLAYERS at once."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from consoled import console_server
from stereopose.site.http.api import clips as clip_api

BOUNDARY = b"--clipframe\r\n"


CLIP = "20240501-130512_7_busbar_cam01.mp4"


def _write_clip(path, frames: int = 6, fps: float = 50.0) -> None:
    w = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps, (64, 48))
    for i in range(frames):
        w.write(np.full((48, 64, 3), 40 * i, np.uint8))
    w.release()


@pytest.fixture
def served(tmp_path):
    with console_server(tmp_path / "out") as s:
        (s.out / "clips").mkdir()
        _write_clip(s.out / "clips" / "20240501-130512_7_busbar_cam01.mp4")
        yield s


def _parts(body: bytes) -> list[np.ndarray]:
    images = []
    for part in body.split(BOUNDARY)[1:]:
        head, _, data = part.partition(b"\r\n\r\n")
        assert b"Content-Type: image/jpeg" in head
        image = cv2.imdecode(np.frombuffer(data.rstrip(b"\r\n"), np.uint8), cv2.IMREAD_COLOR)
        assert image is not None
        images.append(image)
    return images


def test_a_clip_plays_as_motion_jpeg_frame_by_frame(served):
    c = served.client("vera")  # a viewer may watch
    try:
        r = c.get("/api/clips/20240501-130512_7_busbar_cam01.mp4/play")
    finally:
        c.close()
    assert r.status_code == 200, r.text
    assert r.headers["content-type"] == "multipart/x-mixed-replace; boundary=clipframe"
    images = _parts(r.content)
    assert len(images) == 6
    assert [round(float(im.mean()) / 40) for im in images] == [0, 1, 2, 3, 4, 5]
    assert len(clip_api.players) == 0  # its place given back


def test_playing_needs_a_login_and_a_clip_name(served):
    with served.client() as anonymous:
        assert (
            anonymous.get("/api/clips/20240501-130512_7_busbar_cam01.mp4/play").status_code == 401
        )
    c = served.client("vera")
    try:
        for name in ("missing.mp4", "..%2Fusers.json", "users.json", "a.part.mp4"):
            status = c.get(f"/api/clips/{name}/play").status_code
            assert 400 <= status < 500, (name, status)
    finally:
        c.close()
