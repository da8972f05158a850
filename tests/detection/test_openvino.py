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


@pytest.mark.realdata
@pytest.mark.slow
def test_bf16_finds_the_same_people_within_a_few_pixels(frames, reference):
    import openvino as ov

    if "BF16" not in ov.Core().get_property("CPU", "OPTIMIZATION_CAPABILITIES"):
        with pytest.raises(ModelError, match="no bfloat16 instructions"):
            make_detector("openvino", precision="bf16")
        return
    det = make_detector("openvino", threads=1, precision="bf16")
    assert det.runs_in == "bf16"
    found = det.detect(frames)
    assert [len(p) for p in found] == [len(p) for p in reference]
    # bfloat16 keeps 8 bits of mantissa: joints move by a few pixels of a 1088x1920 frame
    # (benchmarks/backends.py measures what that does to the 3D joints)
    for a, b in zip(reference, found, strict=True):
        assert 0.0 < _matched(a, b) < 12.0


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [({"device": "cuda"}, "openvino backend runs on cpu, gpu"),
     ({"device": "gpu.7"}, "finds no such device"),
     ({"precision": "int8"}, "int8 needs the onnx backend")],
)  # fmt: skip
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
