"""Each camera's light where the safety staff and the monitoring look (real browser, real
server, the real demo's frames): a camera at night, one that sees black and one in daylight are
said so on their cards, in /api/cameras and in /metrics."""

from __future__ import annotations

import cv2
import httpx
import numpy as np
import pytest

from browsing import chromium, console_page
from consoled import console_server, demo_plan
from stereopose.detection.light import LightWatch
from stereopose.detection.models import demo_videos

pytestmark = [pytest.mark.slow, pytest.mark.realdata]


def _demo_frames(n: int) -> list[np.ndarray]:
    videos = demo_videos()
    if not videos:
        pytest.skip("the demo videos are not in the cache")
    cap = cv2.VideoCapture(str(videos[0]))
    frames = []
    for _ in range(n):
        ok, frame = cap.read()
        assert ok
        frames.append(frame)
    cap.release()
    return frames


def _label(page, camera: str) -> tuple[str, str, bool]:
    card = page.locator(f'.camera-card[data-camera="{camera}"]')
    node = card.locator(".camera-light")
    return card.get_attribute("data-light") or "", node.inner_text(), node.is_visible()


def test_night_black_and_day_cameras_are_said_so(tmp_path) -> None:
    light = LightWatch()
    black = np.zeros((540, 960, 3), np.uint8)
    for i, frame in enumerate(_demo_frames(40)):
        dark = (frame // 4).astype(np.uint8)  # the demo's own picture, dark: night
        light.prepare({"cam01": frame, "cam02": dark, "cam03": black, "cam04": frame}, i / 10)
    plan = demo_plan(tmp_path)
    with console_server(tmp_path / "out", plan) as s, chromium() as browser:
        s.state.register_light(light.figures)
        c = s.client("vera")
        got = {cam["name"]: cam.get("light") for cam in c.get("/api/cameras").json()["cameras"]}
        c.close()
        assert {n: v["mode"] for n, v in got.items()} == {
            "cam01": "day",
            "cam02": "night",
            "cam03": "black",
            "cam04": "day",
        }
        assert got["cam02"]["brightness"] < 70 < got["cam01"]["brightness"]
        metrics = httpx.get(s.url + "/metrics").text
        assert 'stereopose_camera_light{camera="cam02",mode="night"} 1.0' in metrics
        assert 'stereopose_camera_light{camera="cam02",mode="day"} 0.0' in metrics
        assert 'stereopose_camera_light{camera="cam03",mode="black"} 1.0' in metrics
        assert 'stereopose_camera_brightness{camera="cam01"}' in metrics
        with console_page(browser, s.url, "vera", "light-console") as page:
            page.wait_for_selector('.camera-card[data-camera="cam02"] .camera-light:visible')
            assert _label(page, "cam02") == ("night", "NIGHT", True)
            assert _label(page, "cam03") == ("black", "SEES BLACK", True)
            assert _label(page, "cam01") == ("day", "", False)
            title = page.locator('.camera-card[data-camera="cam02"] .camera-light')
            assert "prepared for the detector" in (title.get_attribute("title") or "")
