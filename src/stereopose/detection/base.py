"""The PoseDetector interface and the YOLO-Pose pre- and post-processing shared by backends.

A detector takes the images of one time step (one per camera, BGR uint8 as OpenCV reads them) and
returns, per image, the people found: 17 COCO keypoints (x, y, visibility) in pixels of the
original image, a box (x1, y1, x2, y2) and a score. Letterboxing and coordinate mapping follow
Ultralytics exactly (same rounding of the padding), so that backends agree to a fraction of a pixel.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import cv2
import numpy as np

from stereopose.skeleton import NUM_JOINTS
from stereopose.types import People2D

PAD_VALUE = 114
MAX_DET = 300  # people kept in one image at most (after non-maximum suppression)


@dataclass(frozen=True)
class Poses:
    """One image's detections: keypoints (P, 17, 3), boxes (P, 4) x1 y1 x2 y2, scores (P,)."""

    keypoints: np.ndarray
    boxes: np.ndarray
    scores: np.ndarray

    def __len__(self) -> int:
        return len(self.scores)

    def people(self, camera: str, frame: int) -> People2D:
        return People2D(camera, frame, self.keypoints, self.boxes, self.scores)

    @staticmethod
    def empty() -> Poses:
        return Poses(np.zeros((0, NUM_JOINTS, 3)), np.zeros((0, 4)), np.zeros(0))


@runtime_checkable
class PoseDetector(Protocol):
    """Anything that finds people and their 17 joints in images: its name, its own input side
    (imgsz: whole frames, long side) and the IoU of its non-maximum suppression."""

    name: str
    imgsz: int
    iou: float

    def detect(self, images: Sequence[np.ndarray], imgsz: int | None = None) -> list[Poses]:
        """One Poses per image, in order; images of one time step are batched where possible.

        imgsz: the model input's side for this call, each image letterboxed into an imgsz x
        imgsz square (the regions of detection.regional, all in one batch); None: the
        detector's own imgsz, long side, padded to the stride (whole frames)."""
        ...


@dataclass(frozen=True)
class Letterbox:
    """How an image of ``shape`` (h, w) is resized into the model input of ``input_shape``."""

    shape: tuple[int, int]
    input_shape: tuple[int, int]
    resized: tuple[int, int]  # (w, h) after resizing
    left: int
    top: int
    right: int
    bottom: int

    @property
    def gain(self) -> tuple[float, float]:
        """(x, y) scale from original to resized pixels."""
        return self.resized[0] / self.shape[1], self.resized[1] / self.shape[0]


def letterbox_for(
    shape: tuple[int, int], imgsz: int | tuple[int, int], stride: int = 32, auto: bool = True
) -> Letterbox:
    """Ultralytics' LetterBox: keep the aspect ratio; ``auto`` pads only to a stride multiple.

    A portrait 1088x1920 frame at imgsz 640 becomes 363x640, padded to 384x640 (10 px left, 11 px
    right), about half the cost of 640x640.
    """
    h, w = int(shape[0]), int(shape[1])
    if h <= 0 or w <= 0:
        raise ValueError(f"empty image of shape {shape}")
    new = (imgsz, imgsz) if isinstance(imgsz, int) else (int(imgsz[0]), int(imgsz[1]))
    r = min(new[0] / h, new[1] / w)
    unpad = (max(round(w * r), 1), max(round(h * r), 1))
    dw, dh = new[1] - unpad[0], new[0] - unpad[1]
    if auto:
        dw, dh = dw % stride, dh % stride
    dw, dh = dw / 2, dh / 2
    top, bottom = round(dh - 0.1), round(dh + 0.1)
    left, right = round(dw - 0.1), round(dw + 0.1)
    return Letterbox(
        (h, w), (unpad[1] + top + bottom, unpad[0] + left + right), unpad, left, top, right, bottom
    )


def letterbox_image(image: np.ndarray, lb: Letterbox) -> np.ndarray:
    """Resize (bilinear) and pad with grey 114, as Ultralytics does."""
    if (image.shape[1], image.shape[0]) != lb.resized:
        image = cv2.resize(image, lb.resized, interpolation=cv2.INTER_LINEAR)
    return cv2.copyMakeBorder(
        image, lb.top, lb.bottom, lb.left, lb.right, cv2.BORDER_CONSTANT, value=(PAD_VALUE,) * 3
    )


def to_blob(images: Sequence[np.ndarray]) -> np.ndarray:
    """BGR uint8 (H, W, 3) images of one size -> RGB float32 (N, 3, H, W) in [0, 1]."""
    batch = np.stack(images)[..., ::-1].transpose(0, 3, 1, 2)
    return np.ascontiguousarray(batch, dtype=np.float32) / np.float32(255.0)


def to_u8_blob(images: Sequence[np.ndarray]) -> np.ndarray:
    """BGR uint8 (H, W, 3) images of one size -> (N, H, W, 3) uint8, for a model that makes
    them RGB float in [0, 1] itself (OpenVINO's preprocessing, compiled into the model)."""
    return np.stack(images)


def nms(boxes: np.ndarray, scores: np.ndarray, iou: float) -> np.ndarray:
    """Greedy non-maximum suppression; kept indices by decreasing score (as torchvision)."""
    order = np.argsort(-scores, kind="stable")
    x1, y1, x2, y2 = boxes.T
    area = (x2 - x1) * (y2 - y1)
    keep = []
    while order.size:
        i = order[0]
        keep.append(i)
        rest = order[1:]
        w = np.clip(np.minimum(x2[i], x2[rest]) - np.maximum(x1[i], x1[rest]), 0, None)
        h = np.clip(np.minimum(y2[i], y2[rest]) - np.maximum(y1[i], y1[rest]), 0, None)
        inter = w * h
        overlap = inter / (area[i] + area[rest] - inter)
        order = rest[~(overlap > iou)]
    return np.asarray(keep, dtype=np.int64)


def decode(output: np.ndarray, lb: Letterbox, conf: float, iou: float, max_det: int) -> Poses:
    """One image's raw pose head (56, N) -> Poses in original pixels.

    Rows: box cx cy w h, person score, then 17 x (x, y, visibility), all in input pixels.
    """
    out = np.asarray(output, dtype=np.float32)
    if out.ndim != 2 or out.shape[0] != 5 + NUM_JOINTS * 3:
        raise ValueError(f"pose head output must have shape (56, N), got {out.shape}")
    cand = out[:, out[4] > conf].T
    if not len(cand):
        return Poses.empty()
    cx, cy, w, h = cand[:, 0], cand[:, 1], cand[:, 2], cand[:, 3]
    boxes = np.stack([cx - w / 2, cy - h / 2, cx + w / 2, cy + h / 2], axis=1)
    scores = cand[:, 4]
    keep = nms(boxes, scores, iou)[:max_det]
    boxes, scores = boxes[keep].astype(np.float64), scores[keep].astype(np.float64)
    kp = cand[keep, 5:].reshape(-1, NUM_JOINTS, 3).astype(np.float64)
    gx, gy = lb.gain
    H, W = lb.shape
    boxes[:, [0, 2]] = np.clip((boxes[:, [0, 2]] - lb.left) / gx, 0, W)
    boxes[:, [1, 3]] = np.clip((boxes[:, [1, 3]] - lb.top) / gy, 0, H)
    kp[..., 0] = np.clip((kp[..., 0] - lb.left) / gx, 0, W)
    kp[..., 1] = np.clip((kp[..., 1] - lb.top) / gy, 0, H)
    return Poses(kp, boxes, scores)


def check_image(image: object, index: int) -> np.ndarray:
    """A BGR uint8 (H, W, 3) image; a grey image is expanded; anything else is a ValueError."""
    a = np.asarray(image)
    if a.ndim == 2:
        a = cv2.cvtColor(a, cv2.COLOR_GRAY2BGR)
    if a.ndim != 3 or a.shape[2] != 3 or a.shape[0] == 0 or a.shape[1] == 0:
        raise ValueError(f"image {index}: expected an (H, W, 3) BGR image, got shape {a.shape}")
    if a.dtype != np.uint8:
        raise ValueError(f"image {index}: expected uint8 pixels, got {a.dtype}")
    return a


def group_by_shape(images: Sequence[np.ndarray]) -> dict[tuple[int, int], list[int]]:
    """Indices of the images sharing each (h, w): one batched inference per group."""
    groups: dict[tuple[int, int], list[int]] = {}
    for i, im in enumerate(images):
        groups.setdefault((im.shape[0], im.shape[1]), []).append(i)
    return groups


class ExportedModel(Protocol):
    """An exported YOLO pose model as `detect_letterboxed` runs it (detection.yolo_onnx,
    detection.yolo_openvino): its input's size and stride, its thresholds, one call."""

    @property
    def dynamic(self) -> bool: ...  # any image size (else `fixed`)
    @property
    def fixed(self) -> tuple[int, int] | None: ...
    @property
    def imgsz(self) -> int: ...
    @property
    def stride(self) -> int: ...
    @property
    def conf(self) -> float: ...
    @property
    def iou(self) -> float: ...
    @property
    def max_det(self) -> int: ...

    def _infer(self, blob: np.ndarray) -> np.ndarray: ...


def detect_letterboxed(
    model: ExportedModel,
    images: Sequence[np.ndarray],
    imgsz: int | None = None,
    blob: Callable[[Sequence[np.ndarray]], np.ndarray] = to_blob,
) -> list[Poses]:
    """The people of each image through an exported YOLO pose model: images of one size
    letterboxed together (model.dynamic: to model.imgsz, padded to model.stride; `imgsz`
    given: every image into an imgsz x imgsz square, so that images of any size make one
    batch; a model of fixed input: to model.fixed), one `model._infer(blob)` -> (B, 56, N) per
    input shape, decoded with model.conf, model.iou and model.max_det (the onnx and openvino
    backends). blob: the letterboxed images of one shape -> the model's input (to_blob:
    RGB float (N, 3, H, W); to_u8_blob for a model that converts them itself)."""
    images = [check_image(im, i) for i, im in enumerate(images)]
    results: list[Poses] = [Poses.empty()] * len(images)
    if not model.dynamic:
        fixed = model.fixed
    elif imgsz is not None:
        fixed = (int(imgsz), int(imgsz))
    else:
        fixed = None
    if fixed is not None:  # one input shape: one batch whatever the images' sizes
        boxes = [letterbox_for(im.shape[:2], fixed, model.stride, auto=False) for im in images]
        if images:
            out = model._infer(
                blob([letterbox_image(im, lb) for im, lb in zip(images, boxes, strict=False)])
            )
            for k, lb in enumerate(boxes):
                results[k] = decode(out[k], lb, model.conf, model.iou, model.max_det)
        return results
    for shape, idx in group_by_shape(images).items():
        lb = letterbox_for(shape, model.imgsz, model.stride, auto=True)
        out = model._infer(blob([letterbox_image(images[i], lb) for i in idx]))
        for k, i in enumerate(idx):
            results[i] = decode(out[k], lb, model.conf, model.iou, model.max_det)
    return results
