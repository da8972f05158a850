"""stereopose: 3D positions and body joints of workers from several fixed cameras."""

from __future__ import annotations

__version__ = "0.1.0"
