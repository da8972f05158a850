"""The site plan's background drawing (the console's Site tab): a PNG or JPEG of the site's
layout placed under the zones by two of its points whose site coordinates are known.

Kept in the service's output folder (`site-plan/background.png` or `.jpg`, and
`background.json`: the two points, each `[u, v, x, y]`: pixels of the drawing, metres of the
site, and the drawing's size). The drawing is checked before anything is written: a PNG or a
JPEG that decodes, at most MAX_SIDE pixels a side; the two points inside it, apart on the
drawing and on the site. Written atomically: a failed upload leaves the one before.
"""

from __future__ import annotations

import json
import math
import struct
import threading
from pathlib import Path

import cv2
import numpy as np

from stereopose.errors import ConfigError
from stereopose.io.writing import make_folder, write_private

__all__ = ["Background"]

MAX_SIDE = 5000  # pixels of the drawing a side, at most (read from its header first)
KINDS = {b"\x89PNG\r\n\x1a\n": ("png", "image/png"), b"\xff\xd8\xff": ("jpg", "image/jpeg")}


def _kind(data: bytes) -> tuple[str, str]:
    for magic, kind in KINDS.items():
        if data.startswith(magic):
            return kind
    raise ConfigError("the drawing: expected a PNG or a JPEG image")


def _header_size(data: bytes, ext: str) -> tuple[int, int] | None:
    """(width, height) from a PNG's IHDR or a JPEG's frame header, before anything is decoded
    (a small file can hold a huge picture); None when the header cannot say."""
    if ext == "png":
        return struct.unpack(">II", data[16:24]) if len(data) >= 24 else None
    i = 2
    while i + 9 < len(data):
        if data[i] != 0xFF:
            return None
        marker, length = data[i + 1], struct.unpack(">H", data[i + 2 : i + 4])[0]
        if marker in (0xC0, 0xC1, 0xC2, 0xC3, 0xC5, 0xC6, 0xC7, 0xC9, 0xCA, 0xCB, 0xCD, 0xCE, 0xCF):
            h, w = struct.unpack(">HH", data[i + 5 : i + 9])
            return w, h
        i += 2 + length
    return None


class Background:
    """See the module; `folder`: where it is kept."""

    def __init__(self, folder: Path) -> None:
        self.folder = Path(folder)
        self._lock = threading.Lock()

    def image(self) -> tuple[bytes, str] | None:
        """(the drawing's bytes, its media type), None when there is none."""
        with self._lock:
            for ext, media in KINDS.values():
                path = self.folder / f"background.{ext}"
                if path.is_file():
                    return path.read_bytes(), media
        return None

    def placement(self) -> dict | None:
        """{"points": [[u, v, x, y], [u, v, x, y]], "size": [w, h]}, None when there is none."""
        with self._lock:
            path = self.folder / "background.json"
            return json.loads(path.read_text(encoding="utf-8")) if path.is_file() else None

    def put(self, data: bytes, points: list[float]) -> dict:
        """The drawing and its two points (u1, v1, x1, y1, u2, v2, x2, y2) kept: its
        placement. ConfigError naming the problem, nothing written."""
        ext, _ = _kind(data)
        size = _header_size(data, ext)
        if size is None:
            raise ConfigError(f"the drawing: not a {ext.upper()} that decodes")
        if max(size) > MAX_SIDE or min(size) < 1:
            raise ConfigError(f"the drawing: {size[0]}x{size[1]} pixels; 1 to {MAX_SIDE} a side")
        image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
        if image is None:
            raise ConfigError(f"the drawing: not a {ext.upper()} that decodes")
        h, w = image.shape[:2]
        if len(points) != 8 or not all(math.isfinite(v) and abs(v) <= 1e6 for v in points):
            raise ConfigError("points: expected 8 finite numbers: u1 v1 x1 y1 u2 v2 x2 y2")
        pairs = [points[0:4], points[4:8]]
        for k, (u, v, _, _) in enumerate(pairs, 1):
            if not (0 <= u <= w and 0 <= v <= h):
                raise ConfigError(f"point {k}: ({u:g}, {v:g}) is not in the {w}x{h} drawing")
        (u1, v1, x1, y1), (u2, v2, x2, y2) = pairs
        if math.hypot(u2 - u1, v2 - v1) < 10 or math.hypot(x2 - x1, y2 - y1) < 0.1:
            raise ConfigError("points: at least 10 px apart on the drawing and 0.1 m on the site")
        placement = {"points": pairs, "size": [w, h]}
        with self._lock:
            make_folder(self.folder)
            for other, _ in KINDS.values():
                if other != ext:
                    (self.folder / f"background.{other}").unlink(missing_ok=True)
            write_private(self.folder / f"background.{ext}", data)
            write_private(self.folder / "background.json", json.dumps(placement).encode())
        return placement

    def delete(self) -> bool:
        """The drawing taken away; whether there was one."""
        with self._lock:
            found = False
            for name in ("background.png", "background.jpg", "background.json"):
                path = self.folder / name
                found |= path.is_file()
                path.unlink(missing_ok=True)
            return found
