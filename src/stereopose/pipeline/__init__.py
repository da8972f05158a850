"""Wires the stages together; the only package that knows them all.

``loop`` is the one frame loop (source -> detection -> 3D stage -> fences -> sinks) that
``reconstruct`` (2D keypoint files), ``run`` (cameras) and the demo share; ``outputs`` opens
the sinks a run writes; ``detect`` runs cameras through a pose detector into 2D keypoint files;
``calibrate`` computes a rig from checkerboard photos.
"""

from stereopose.io.sinks import write_trajectories
from stereopose.io.summary import RunSummary
from stereopose.pipeline.calibrate import (
    ExtrinsicsRun,
    IntrinsicsRun,
    calibrate_extrinsics_dir,
    calibrate_intrinsics_dir,
)
from stereopose.pipeline.detect import DetectionSummary, detect_videos
from stereopose.pipeline.loop import FrameLoop, SourceStep, run_frames
from stereopose.pipeline.outputs import Outputs, open_outputs
from stereopose.pipeline.reconstruct import evaluate_poses_file, reconstruct_files

__all__ = [
    "DetectionSummary",
    "ExtrinsicsRun",
    "FrameLoop",
    "IntrinsicsRun",
    "Outputs",
    "RunSummary",
    "SourceStep",
    "calibrate_extrinsics_dir",
    "calibrate_intrinsics_dir",
    "detect_videos",
    "evaluate_poses_file",
    "open_outputs",
    "reconstruct_files",
    "run_frames",
    "write_trajectories",
]
