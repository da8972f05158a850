"""The INT8 pose model: chosen by precision, quantised offline, finds the demo's people."""

from __future__ import annotations

import numpy as np
import pytest

from demo_frames import demo_step
from stereopose.detection import ModelError, make_detector


@pytest.mark.parametrize(
    ("backend", "precision", "message"),
    [
        ("onnx", "fp8", "precision must be auto or one of fp32, bf16, int8, fp16"),
        ("ultralytics", "int8", "int8 needs the onnx or openvino backend"),
    ],
)
def test_an_unknown_precision_or_backend_is_refused(backend, precision, message):
    with pytest.raises(ModelError, match=message):
        make_detector(backend, precision=precision)


@pytest.mark.realdata
@pytest.mark.slow
def test_int8_model_finds_the_people_fp32_finds_in_a_real_demo_frame():
    frame = demo_step(50)[0]
    q = make_detector(precision="int8", threads=1)
    assert q.model.name.endswith("-int8.onnx")
    found = q.detect([frame])[0]
    ref = make_detector("onnx", threads=1).detect([frame])[0]
    assert len(found) >= 1 and len(ref) >= 1
    # every person FP32 finds, INT8 finds in the same place (its joints: benchmarks/int8.py)
    assert len(found) == len(ref)
    for box in ref.boxes:
        assert max(_iou(box, other) for other in found.boxes) > 0.7


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    w = max(0.0, min(a[2], b[2]) - max(a[0], b[0]))
    h = max(0.0, min(a[3], b[3]) - max(a[1], b[1]))
    union = (a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - w * h
    return w * h / union
