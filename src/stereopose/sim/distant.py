"""Distant-worker variants of real frames: each frame shrunk into a larger grey canvas, as a
wide substation camera mounted high sees workers 8-10 m away, with the calibration made to
match (the intrinsics scaled and shifted, the lens and the pose unchanged), so that the real
people of a real recording stand where a far camera would see them."""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np

from stereopose.types import Camera, Rig

CANVAS = (1920, 1080)  # width, height: a wide 1080p camera
GREY = 114


@dataclasses.dataclass(frozen=True)
class Distant:
    """Frames shrunk by `scale` and pasted with their top-left corner at `at` (x, y) into a
    `canvas` (w, h) of grey."""

    scale: float
    at: tuple[int, int] = (800, 300)
    canvas: tuple[int, int] = CANVAS

    def __post_init__(self) -> None:
        if not 0 < self.scale <= 1:
            raise ValueError(f"scale must be in (0, 1], got {self.scale}")

    def frame(self, image: np.ndarray) -> np.ndarray:
        """(H, W, 3) BGR -> (canvas h, canvas w, 3): the image shrunk and pasted."""
        h, w = image.shape[:2]
        sw, sh = round(w * self.scale), round(h * self.scale)
        x0, y0 = self.at
        cw, ch = self.canvas
        if x0 < 0 or y0 < 0 or x0 + sw > cw or y0 + sh > ch:
            raise ValueError(
                f"a {w}x{h} frame at scale {self.scale} does not fit the {cw}x{ch} "
                f"canvas at {self.at}"
            )
        out = np.full((ch, cw, 3), GREY, np.uint8)
        out[y0 : y0 + sh, x0 : x0 + sw] = cv2.resize(image, (sw, sh), interpolation=cv2.INTER_AREA)
        return out

    def empty(self) -> np.ndarray:
        """The canvas with nothing pasted."""
        return np.full((self.canvas[1], self.canvas[0], 3), GREY, np.uint8)

    def camera(self, camera: Camera) -> Camera:
        """The camera that sees the canvas: its pixels scaled and shifted as the frames are
        (the lens's distortion acts on normalised coordinates, which do not change)."""
        sx = round(camera.size[0] * self.scale) / camera.size[0]
        sy = round(camera.size[1] * self.scale) / camera.size[1]
        K = np.array(camera.matrix, dtype=np.float64)
        K[0] *= sx
        K[1] *= sy
        # a resized pixel's centre: (u + 0.5) * s - 0.5, as cv2.resize maps them
        K[0, 2] += self.at[0] + 0.5 * sx - 0.5
        K[1, 2] += self.at[1] + 0.5 * sy - 0.5
        K[2] = (0.0, 0.0, 1.0)
        return Camera(
            camera.name,
            self.canvas,
            K,
            camera.distortions,
            camera.rotation,
            camera.translation,
            camera.fisheye,
        )

    def rig(self, rig: Rig) -> Rig:
        return Rig(tuple(self.camera(c) for c in rig))
