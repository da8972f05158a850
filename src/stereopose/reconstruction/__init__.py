"""Per-frame 3D people from the 2D people of every camera."""

from stereopose.reconstruction.reconstructor import Reconstructor

__all__ = ["Reconstructor"]
