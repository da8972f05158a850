"""Wires the stages together; the only package that knows them all.

``detect`` runs cameras through a pose detector into 2D keypoint files, ``reconstruct`` turns 2D
keypoints into 3D poses, tracks and events, ``calibrate`` computes a rig from checkerboard photos.
"""

from stereopose.pipeline.calibrate import (
    ExtrinsicsRun,
    IntrinsicsRun,
    calibrate_extrinsics_dir,
    calibrate_intrinsics_dir,
)
from stereopose.pipeline.detect import DetectionSummary, detect_videos
from stereopose.pipeline.reconstruct import evaluate_poses_file, reconstruct_files
from stereopose.pipeline.stages import Back3D, ReconstructionSummary, write_trajectories

__all__ = [
    "Back3D",
    "DetectionSummary",
    "ExtrinsicsRun",
    "IntrinsicsRun",
    "ReconstructionSummary",
    "calibrate_extrinsics_dir",
    "calibrate_intrinsics_dir",
    "detect_videos",
    "evaluate_poses_file",
    "reconstruct_files",
    "write_trajectories",
]
