"""Each camera's light: the real demo is day and goes to the detector unchanged; a night
version of it (grey, darker, half the contrast, strong temporal noise, encoded as a camera
would: ffmpeg's recipe) is known as night, and its pictures prepared for the detector give
back the people the noise hid; a black or blinded camera is said so."""

from __future__ import annotations

import itertools
import subprocess
from pathlib import Path

import cv2
import numpy as np
import pytest

from stereopose.detection import make_detector
from stereopose.detection.light import LightWatch, measure
from stereopose.detection.models import demo_videos
from streams import ffmpeg

pytestmark = [pytest.mark.realdata]

NIGHT = "format=gray,eq=brightness=-0.25:contrast=0.5,noise=alls=25:allf=t"
FRAMES = 40


def _frames(videos: list[Path], n: int = FRAMES) -> list[dict[str, np.ndarray]]:
    caps = [cv2.VideoCapture(str(v)) for v in videos]
    out = []
    for _ in range(n):
        step = {}
        for v, c in zip(videos, caps, strict=True):
            ok, frame = c.read()
            assert ok, v
            step[v.stem] = frame
        out.append(step)
    for c in caps:
        c.release()
    return out


@pytest.fixture(scope="module")
def day() -> list[dict[str, np.ndarray]]:
    videos = demo_videos()
    if not videos:
        pytest.skip("the demo videos are not in the cache")
    return _frames(videos)


@pytest.fixture(scope="module")
def night(tmp_path_factory) -> list[dict[str, np.ndarray]]:
    videos = demo_videos()
    if not videos:
        pytest.skip("the demo videos are not in the cache")
    folder = tmp_path_factory.mktemp("night")
    out = []
    for v in videos:
        target = folder / v.name
        cmd = [ffmpeg(), "-loglevel", "error", "-y", "-i", str(v), "-frames:v", str(FRAMES)]
        cmd += ["-vf", NIGHT, "-c:v", "libx264", "-preset", "veryfast", "-pix_fmt", "yuv420p"]
        subprocess.run([*cmd, str(target)], check=True, timeout=120)
        out.append(target)
    return _frames(out)


def test_the_day_demo_is_day_and_goes_to_the_detector_unchanged(day) -> None:
    light = LightWatch()
    for i, step in enumerate(day[:15]):
        seen = light.prepare(step, i / 60)
        assert all(seen[n] is step[n] for n in step)  # the same arrays, untouched
    figures = light.figures()
    assert {f["mode"] for f in figures.values()} == {"day"}
    assert all(f["prepared_steps"] == 0 and f["brightness"] > 90 for f in figures.values())


@pytest.mark.slow
def test_a_night_camera_is_known_and_its_people_found_again(day, night) -> None:
    light = LightWatch()
    detector = make_detector(threads=2)
    found = {"day": 0, "night": 0, "prepared": 0}
    for i, (d, n) in enumerate(zip(day, night, strict=True)):
        seen = light.prepare(n, i / 60)
        if i < 8 or i % 4:
            continue
        for key, images in (("day", d), ("night", n), ("prepared", seen)):
            found[key] += sum(len(p) for p in detector.detect(list(images.values())))
    figures = light.figures()
    assert {f["mode"] for f in figures.values()} == {"night"}, figures
    assert all(f["noise"] > 6 and f["colour"] < 10 for f in figures.values()), figures
    # the recipe hides people (about a third of them); prepared, they are found again
    assert found["night"] < 0.8 * found["day"], found
    assert found["prepared"] >= 0.95 * found["day"], found


def test_black_and_blinded_cameras_are_said_so_and_a_camera_comes_back_to_day(day) -> None:
    light = LightWatch()
    black = np.zeros((540, 960, 3), np.uint8)
    white = np.full((540, 960, 3), 255, np.uint8)
    for i in range(40):
        seen = light.prepare({"a": black, "b": white}, i / 10)
        assert seen["a"] is black and seen["b"] is white  # nothing to prepare
    assert light.mode("a") == "black" and light.mode("b") == "blinded"
    dark = (day[0]["cam01"] // 4).astype(np.uint8)  # a dark picture: night
    for i in range(40):
        light.prepare({"c": dark}, i / 10)
    assert light.mode("c") == "night"
    for i, step in enumerate(day[:40]):
        light.prepare({"c": step["cam01"]}, 4 + i / 10)
    assert light.mode("c") == "day" and light.figures()["c"]["changes"] == 2
    assert light._cameras["c"].average is None  # a camera back to day holds nothing


def test_the_measure_reads_grey_and_colour_frames() -> None:
    rng = np.random.default_rng(1)
    flat = np.full((480, 640), 100, np.uint8)
    noisy = np.clip(flat + rng.normal(0, 10, flat.shape), 0, 255).astype(np.uint8)
    m0, m1 = measure(flat), measure(cv2.cvtColor(noisy, cv2.COLOR_GRAY2BGR))
    assert m0["noise"] < 0.5 and 8 < m1["noise"] < 12  # sigma 10 estimated
    assert m1["colour"] == 0 and abs(m1["brightness"] - 100) < 2


def test_the_cameras_measures_fall_on_different_steps():
    """Every camera is measured at its first step, then every MEASURE_EVERY steps, the
    cameras staggered: after the first step, a step of four cameras measures at most one (not
    all four at once every fifth step, a step four measures slower)."""
    from stereopose.detection.light import MEASURE_EVERY

    rng = np.random.default_rng(3)
    names = ["cam01", "cam02", "cam03", "cam04"]
    frame = rng.integers(60, 200, (240, 320, 3), dtype=np.uint8)
    light = LightWatch()
    counts = []
    for i in range(4 * MEASURE_EVERY + 1):
        light.prepare(dict.fromkeys(names, frame), i / 10)
        counts.append([light.figures()[n]["measures"] for n in names])
    assert counts[0] == [1, 1, 1, 1]
    per_step = [sum(b) - sum(a) for a, b in itertools.pairwise(counts)]
    assert max(per_step) == 1, per_step
    assert counts[-1] == [5, 5, 5, 5]  # one every MEASURE_EVERY steps each
