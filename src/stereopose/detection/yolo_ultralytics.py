"""YOLO-Pose through the ultralytics package (PyTorch), from a local weights file only."""

from __future__ import annotations

import logging
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from stereopose.detection.base import MAX_DET, Poses, check_image, group_by_shape
from stereopose.detection.models import ModelError, check_weights, offline_environment

logger = logging.getLogger(__name__)


class UltralyticsPoseDetector:
    """A local YOLO pose model (.pt, or any format ultralytics reads) run by ultralytics."""

    name = "ultralytics"
    max_det = MAX_DET  # people kept in one image at most

    def __init__(
        self,
        model: str | Path,
        imgsz: int = 640,
        conf: float = 0.25,
        iou: float = 0.7,
        device: str = "cpu",
        threads: int | None = None,
    ) -> None:
        offline_environment()
        self.model_path = check_weights(Path(model))
        try:
            import torch
            from ultralytics import YOLO
            from ultralytics.utils import SETTINGS
        except ImportError as e:
            raise ModelError(
                f"the ultralytics backend needs the ultralytics package ({e}); `make install` "
                "installs it, or use --backend onnx"
            ) from None
        SETTINGS.update(sync=False)
        if threads:
            torch.set_num_threads(threads)
        try:
            self.model = YOLO(str(self.model_path), task="pose")
        except Exception as e:  # ultralytics raises many kinds on a bad file
            raise ModelError(f"{self.model_path}: not a readable YOLO model: {e}") from None
        if self.model.task != "pose":
            raise ModelError(f"{self.model_path}: a {self.model.task} model, not a pose model")
        self.imgsz, self.conf, self.iou = imgsz, conf, iou
        self.device = "cpu" if device == "auto" and not torch.cuda.is_available() else device
        if self.device == "auto":
            self.device = "cuda"

    def detect(self, images: Sequence[np.ndarray], imgsz: int | None = None) -> list[Poses]:
        from ultralytics.engine.results import Results

        images = [check_image(im, i) for i, im in enumerate(images)]
        results: list[Poses] = [Poses.empty()] * len(images)
        for idx in group_by_shape(images).values():
            batch = self.model.predict(
                [images[i] for i in idx],
                imgsz=imgsz or self.imgsz,
                conf=self.conf,
                iou=self.iou,
                max_det=self.max_det,
                device=self.device,
                verbose=False,
            )
            for i, r in zip(idx, batch, strict=False):
                assert isinstance(r, Results)  # predict's results, not a stream's tensors
                keypoints, boxes = r.keypoints, r.boxes
                if keypoints is None or boxes is None or not len(boxes):
                    continue
                results[i] = Poses(_array(keypoints.data), _array(boxes.xyxy), _array(boxes.conf))
        return results


def _array(x: object) -> np.ndarray:
    """A result's tensor (or array) as float64 NumPy."""
    import torch

    return np.asarray(x.cpu().numpy() if isinstance(x, torch.Tensor) else x, dtype=np.float64)
