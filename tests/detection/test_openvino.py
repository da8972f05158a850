"""The openvino backend: the same ONNX model on OpenVINO, fp32 as exact as ONNX Runtime, bf16
close to it, and clear errors for what it cannot run."""

from __future__ import annotations

import numpy as np
import pytest

from demo_frames import demo_step
from stereopose.config import Config, ConfigError, from_dict
from stereopose.detection import ModelError, make_detector

pytest.importorskip("openvino")


@pytest.fixture(scope="module")
def frames() -> list[np.ndarray]:
    return demo_step(30)


@pytest.fixture(scope="module")
def reference(frames):
    return make_detector("onnx", threads=1).detect(frames)


def _matched(a, b) -> np.ndarray:
    """The largest joint displacement (px) between two detections of one image, each person
    of `a` matched to the nearest box of `b`."""
    assert len(a) == len(b)
    worst = 0.0
    for k, box in enumerate(a.boxes):
        j = int(np.argmin(np.abs(b.boxes - box).sum(axis=1)))
        seen = (a.keypoints[k, :, 2] > 0.5) & (b.keypoints[j, :, 2] > 0.5)
        d = np.linalg.norm(a.keypoints[k, seen, :2] - b.keypoints[j, seen, :2], axis=1)
        worst = max(worst, float(d.max(initial=0.0)))
    return worst


@pytest.mark.realdata
@pytest.mark.slow
def test_fp32_finds_what_onnx_runtime_finds_to_a_tenth_of_a_pixel(frames, reference):
    det = make_detector("openvino", threads=1, precision="fp32")
    assert det.name == "openvino" and det.runs_in == "f32"
    found = det.detect(frames)
    assert [len(p) for p in found] == [len(p) for p in reference]
    assert all(len(p) >= 2 for p in found)
    for a, b in zip(reference, found, strict=True):
        assert _matched(a, b) < 0.1
        assert np.allclose(a.scores, b.scores, atol=1e-3)


# bf16 keeps 8 bits of mantissa. Measured against ONNX Runtime fp32 on the real demo
# (benchmarks/results/backends.md, 25 steps) the two kinds of CPU agree: on an Intel Xeon
# with AMX median 0.57 px, p95 5.6 px; on an AMD EPYC with AVX512_BF16 median 0.59 px, p95
# 5.9 px; 94 % of joints within 5 px on both. Pooled over five steps (about 720 joints) the
# AMD EPYC gave medians 0.63-0.70 px and p95s 3.5-9.6 px. A few joints whose heatmap is
# ambiguous jump by 20-130 px on both CPUs, in a different step on each: the worst single
# joint describes the rounding of one CPU, not the backend, and is not bounded here.
BF16_STEPS = (10, 30, 50, 70, 90)
BF16_MEDIAN_PX = 1.5  # about twice the worst five-step median measured
BF16_P95_PX = 15.0  # about 1.5x the worst five-step p95 measured
BF16_WITHIN_5PX = 0.85  # 0.92-0.97 measured over five steps


def _displacements(a, b) -> np.ndarray:
    """The displacement (px) of every joint both detections of one image see confidently,
    each person of `a` matched to the nearest box of `b`."""
    out = []
    for k, box in enumerate(a.boxes):
        j = int(np.argmin(np.abs(b.boxes - box).sum(axis=1)))
        seen = (a.keypoints[k, :, 2] > 0.5) & (b.keypoints[j, :, 2] > 0.5)
        out.append(np.linalg.norm(a.keypoints[k, seen, :2] - b.keypoints[j, seen, :2], axis=1))
    return np.concatenate(out) if out else np.zeros(0)


@pytest.mark.realdata
@pytest.mark.slow
def test_bf16_finds_the_same_people_within_a_few_pixels():
    from stereopose.detection.openvino_core import ov_core

    if "BF16" not in ov_core().get_property("CPU", "OPTIMIZATION_CAPABILITIES"):
        with pytest.raises(ModelError, match="no bfloat16 instructions"):
            make_detector("openvino", precision="bf16")
        return
    det = make_detector("openvino", threads=2, precision="bf16")
    assert det.runs_in == "bf16"
    ref = make_detector("onnx", threads=2)
    moved = []
    for index in BF16_STEPS:
        step = demo_step(index)
        reference, found = ref.detect(step), det.detect(step)
        assert [len(p) for p in found] == [len(p) for p in reference], index
        moved += [_displacements(a, b) for a, b in zip(reference, found, strict=True)]
    d = np.concatenate(moved)
    assert d.size > 500  # the demo's people, confidently seen
    assert 0.0 < np.median(d) < BF16_MEDIAN_PX  # bf16 really ran, and moved joints a little
    assert np.quantile(d, 0.95) < BF16_P95_PX
    assert (d <= 5.0).mean() >= BF16_WITHIN_5PX


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"device": "cuda"}, "openvino backend runs on cpu, gpu"),
        ({"device": "gpu.7"}, "finds no such device"),
        ({"precision": "fp16"}, "fp16 needs the onnx backend"),
    ],
)
def test_what_it_cannot_run_is_a_clear_error(kwargs, message):
    with pytest.raises(ModelError, match=message):
        make_detector("openvino", **kwargs)


def test_a_file_that_is_not_a_model_names_the_file(tmp_path):
    bad = tmp_path / "broken.onnx"
    bad.write_bytes(b"not a model")
    with pytest.raises(ModelError, match=r"broken\.onnx: not a readable ONNX model"):
        make_detector("openvino", bad)


def test_the_configuration_takes_the_backend_and_refuses_bf16_elsewhere():
    cfg = from_dict(Config, {"detector": {"backend": "openvino", "precision": "bf16"}}, "")
    assert (cfg.detector.backend, cfg.detector.precision) == ("openvino", "bf16")
    with pytest.raises(ConfigError, match=r"detector\.backend"):
        from_dict(Config, {"detector": {"backend": "openvina"}}, "")
    with pytest.raises(ModelError, match="bf16 needs the openvino backend"):
        make_detector("onnx", precision="bf16")
