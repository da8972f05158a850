"""Each camera's light, and its pictures made easier for the detector in the dark.

    light = LightWatch()                       # one for all cameras of a run or a service
    images = light.prepare(images, t)          # before detection: {camera: BGR frame}
    light.figures()                            # per camera: mode, brightness, contrast, ...

Per camera, at its first step and then every MEASURE_EVERY steps (the cameras' measures on
different steps), a cheap measure of the frame already decoded:
- brightness: the mean grey level (0-255) of a small copy;
- contrast: the grey levels' standard deviation there;
- noise: the sensor noise's standard deviation in grey levels, from the full-resolution
  centre (Immerkaer's estimate: the picture's second differences, which edges barely feed);
- colour: the mean difference between the colour channels (an infrared camera's grey: ~0).

Smoothed over the last measures, they give the camera's mode: "day"; "night" (dark or noisy:
brightness below 70 or noise above 6, left again only when both are clear by a margin; a flat
picture alone, fog or an empty yard, is no night); "black" (nothing to see: a covered lens, a
dead sensor) or "blinded" (white: the sun, a lamp into the lens). Only a camera at night is
prepared; any other picture goes to the detector as it came, the same array.

Night preparation, on the grey picture: temporal denoising where the scene is still (a running
average, each pixel's kept while it stays within 3 noise sigmas of it; a moving pixel takes
the new frame, smoothed spatially), then contrast normalisation (CLAHE, 8 x 8 tiles). The
detector gets it as a 3-channel grey frame; clips and snapshots keep the camera's own picture.
Memory: per night camera one float running average of its frame.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass, field

import cv2
import numpy as np

__all__ = ["LightWatch", "measure"]

MEASURE_EVERY = 5  # steps between two measures of a camera
SMOOTH = 6  # measures a camera's mode rests on (their median)
THUMB = 160  # the small copy's width for brightness, contrast and colour
NOISE_CROP = 256  # the full-resolution centre square the noise is estimated on
DARK, NOISY = 70.0, 6.0  # night below/above these
CLEAR = 1.15  # back to day only when every figure is clear of its line by this factor
BLACK_BRIGHT, BLACK_CONTRAST = 10.0, 4.0
BLIND_BRIGHT, BLIND_CONTRAST = 240.0, 6.0
WORK_SIDE = 960  # a night picture is prepared with its long side at most this (then scaled back)
AVERAGE = 0.35  # weight of a new frame in a still pixel's running average
MODES = ("day", "night", "black", "blinded")
_KERNEL = np.array([[1, -2, 1], [-2, 4, -2], [1, -2, 1]], np.float32)


def _thumb(image: np.ndarray) -> np.ndarray:
    """The frame THUMB pixels wide, each pixel its area's mean: shrunk first by a whole factor
    (OpenCV's fast block means, the frame's last few rows and columns left out), then to
    THUMB (about 1 ms for a full-HD frame, against 4 ms straight)."""
    h, w = image.shape[:2]
    size = (THUMB, max(1, round(THUMB * h / w)))
    k = min(w // size[0], h // size[1])
    if k >= 2:
        hk, wk = h - h % k, w - w % k
        image = cv2.resize(image[:hk, :wk], (wk // k, hk // k), interpolation=cv2.INTER_AREA)
    return cv2.resize(image, size, interpolation=cv2.INTER_AREA)


def measure(image: np.ndarray) -> dict[str, float]:
    """brightness, contrast, noise and colour of one BGR (or grey) frame; see the module."""
    h, w = image.shape[:2]
    c = min(NOISE_CROP, h, w)
    y0, x0 = (h - c) // 2, (w - c) // 2
    centre = image[y0 : y0 + c, x0 : x0 + c]
    small = _thumb(image)
    if image.ndim == 2:
        small_grey, grey_centre, colour = small, centre, 0.0
    else:
        s = small.astype(np.int16)
        colour = float((np.abs(s[..., 0] - s[..., 1]) + np.abs(s[..., 1] - s[..., 2])).mean() / 2.0)
        small_grey = cv2.cvtColor(small, cv2.COLOR_BGR2GRAY)
        grey_centre = cv2.cvtColor(np.ascontiguousarray(centre), cv2.COLOR_BGR2GRAY)
    crop = grey_centre.astype(np.float32)
    lap = cv2.filter2D(crop, -1, _KERNEL)[1:-1, 1:-1]
    noise = float(np.sqrt(np.pi / 2.0) * np.abs(lap).mean() / 6.0) if lap.size else 0.0
    return {
        "brightness": float(small_grey.mean()),
        "contrast": float(small_grey.std()),
        "noise": noise,
        "colour": colour,
    }


def _mode(m: Mapping[str, float], was: str) -> str:
    """The light's mode from smoothed figures, with hysteresis out of night."""
    b, c, n = m["brightness"], m["contrast"], m["noise"]
    if b < BLACK_BRIGHT and c < BLACK_CONTRAST:
        return "black"
    if b > BLIND_BRIGHT and c < BLIND_CONTRAST:
        return "blinded"
    if b < DARK or n > NOISY:
        return "night"
    if was == "night" and (b < DARK * CLEAR or n > NOISY / CLEAR):
        return "night"
    return "day"


@dataclass
class _Camera:
    measures: deque = field(default_factory=lambda: deque(maxlen=SMOOTH))
    figures: dict[str, float] = field(default_factory=dict)
    mode: str = "day"
    steps: int = 0
    # its measures fall on other steps than the other cameras' (staggered: a step measures
    # about one camera in MEASURE_EVERY, not all of them at once every MEASURE_EVERY steps)
    phase: int = 0
    measured: int = 0  # measures taken
    changes: int = 0  # mode changes
    since_t: float = 0.0  # the step time its mode began
    prepared: int = 0  # steps its picture was prepared for the detector
    prepare_s: float = 0.0
    average: np.ndarray | None = None  # the night running average (float32 grey)


class LightWatch:
    """See the module. enhance: prepare night pictures (False: only measure)."""

    def __init__(self, enhance: bool = True) -> None:
        self.enhance = bool(enhance)
        self._cameras: dict[str, _Camera] = {}
        self._lock = threading.Lock()  # figures() from the HTTP threads
        self._clahe = cv2.createCLAHE(clipLimit=2.0, tileGridSize=(8, 8))

    def prepare(self, images: Mapping[str, np.ndarray], t: float) -> dict[str, np.ndarray]:
        """The frames the detector is to see: a night camera's prepared, every other one the
        same array it came as."""
        out = dict(images)
        for name, image in images.items():
            if image is None:
                continue
            cam = self._cameras.get(name)
            if cam is None:
                phase = len(self._cameras) % MEASURE_EVERY
                cam = self._cameras[name] = _Camera(since_t=t, phase=phase)
            if cam.steps == 0 or (cam.steps + cam.phase) % MEASURE_EVERY == 0:
                self._measure(cam, image, t)
            cam.steps += 1
            if self.enhance and cam.mode == "night":
                t0 = time.perf_counter()
                out[name] = self._night(cam, image)
                cam.prepare_s += time.perf_counter() - t0
                cam.prepared += 1
            else:
                cam.average = None  # a camera back to day holds nothing
        return out

    def _measure(self, cam: _Camera, image: np.ndarray, t: float) -> None:
        cam.measures.append(measure(image))
        cam.measured += 1
        smooth = {k: float(np.median([m[k] for m in cam.measures])) for k in cam.measures[0]}
        mode = _mode(smooth, cam.mode)
        with self._lock:
            cam.figures = smooth
            if mode != cam.mode:
                cam.mode, cam.since_t = mode, t
                cam.changes += 1

    def _night(self, cam: _Camera, image: np.ndarray) -> np.ndarray:
        grey = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
        h, w = grey.shape[:2]
        scale = min(1.0, WORK_SIDE / max(h, w))
        if scale < 1.0:  # worked on at the detector's detail or finer (and averaged: less noise)
            size = (max(1, round(w * scale)), max(1, round(h * scale)))
            grey = cv2.resize(grey, size, interpolation=cv2.INTER_AREA)
        g = grey.astype(np.float32)
        if cam.average is None or cam.average.shape != g.shape:
            cam.average = cv2.GaussianBlur(g, (5, 5), 0)
        sigma = max(cam.figures.get("noise", 0.0) * max(scale, 0.5), 1.0)  # averaged down
        moving = cv2.absdiff(g, cam.average) > 3.0 * sigma
        cv2.accumulateWeighted(g, cam.average, AVERAGE)
        smooth = cv2.GaussianBlur(g, (5, 5), 0)
        cam.average[moving] = smooth[moving]  # a moving pixel starts again from the new frame
        out = self._clahe.apply(np.clip(cam.average, 0, 255).astype(np.uint8))
        if scale < 1.0:
            out = cv2.resize(out, (w, h), interpolation=cv2.INTER_LINEAR)
        return cv2.cvtColor(out, cv2.COLOR_GRAY2BGR)

    def mode(self, name: str) -> str | None:
        cam = self._cameras.get(name)
        return None if cam is None else cam.mode

    def figures(self) -> dict[str, dict]:
        """Per camera: its mode and since when (step time), the smoothed figures, mode
        changes, measures taken, steps prepared and the milliseconds a preparation took on
        average."""
        with self._lock:
            return {
                name: {
                    "mode": c.mode,
                    "since_t": round(c.since_t, 3),
                    **{k: round(v, 2) for k, v in c.figures.items()},
                    "changes": c.changes,
                    "measures": c.measured,
                    "prepared_steps": c.prepared,
                    "prepare_ms": round(1000 * c.prepare_s / c.prepared, 2) if c.prepared else 0.0,
                }
                for name, c in self._cameras.items()
            }
