"""Per-frame 3D people from the 2D people of every camera (stateless per frame, given a prior)."""

from stereopose.reconstruction.reconstructor import Reconstruction, Reconstructor

__all__ = ["Reconstruction", "Reconstructor"]
