"""The overlay videos as a sink of the frame loop (drawn by viz.overlay)."""

from __future__ import annotations

from pathlib import Path

from stereopose.io.sinks.base import ClosesOnce, FrameResult
from stereopose.types import Rig
from stereopose.viz.overlay import OverlayVideo


class OverlaySink(ClosesOnce):
    """One MP4 per camera, `<out_dir>/<camera>.mp4`: its frames with the detections and the
    3D people reprojected; a frame is drawn for each camera with 2D people at that step. Its
    time counts in the summary's "overlays" stage. Keypoint input has no images: nothing is
    written."""

    stage = "overlays"

    def __init__(self, rig: Rig, out_dir: str | Path, fps: float, scale: float = 0.5) -> None:
        out_dir = Path(out_dir)
        self.videos = {c.name: OverlayVideo(out_dir / f"{c.name}.mp4", c, fps, scale) for c in rig}

    def write(self, frame: FrameResult) -> None:
        if frame.images is None:
            return
        label = f"{frame.frame}  t={frame.t:.2f}s"
        for name, p2 in frame.people2d.items():
            video = self.videos.get(name)
            image = frame.images.get(name)
            if video is not None and image is not None:
                video.write(image, p2, frame.people3d, label)

    def _close(self) -> list[Path]:
        paths = [v.close() for v in self.videos.values()]
        return [p for p in paths if p is not None]
