"""The onnx backend's devices: ONNX Runtime's providers chosen for cpu, cuda[:N], tensorrt[:N]
and auto, clear errors for what this ONNX Runtime lacks, and the cameras of a step in one batch
(in chunks of max_batch) giving what one image at a time gives."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from demo_frames import demo_step
from stereopose.detection import ModelError, make_detector
from stereopose.detection.yolo_onnx import (
    CPU,
    CUDA,
    TENSORRT,
    OnnxPoseDetector,
    _providers,
    parse_device,
    trt_profile,
)

ALL = [TENSORRT, CUDA, CPU]


@pytest.mark.parametrize(
    ("device", "expected"),
    [
        ("cpu", ("cpu", 0)),
        ("auto", ("auto", 0)),
        ("cuda", ("cuda", 0)),
        ("gpu", ("cuda", 0)),
        ("cuda:2", ("cuda", 2)),
        ("3", ("cuda", 3)),
        (" CUDA:1 ", ("cuda", 1)),
        ("tensorrt", ("tensorrt", 0)),
        ("tensorrt:1", ("tensorrt", 1)),
    ],
)
def test_a_device_names_a_kind_and_a_gpu(device, expected):
    assert parse_device(device) == expected


@pytest.mark.parametrize("device", ["cuda:x", "tensorrt:-1", "trt", "gpu.0", "", "cuda:"])
def test_a_device_it_does_not_know_is_refused(device):
    with pytest.raises(ModelError, match="expected cpu, cuda, cuda:N, tensorrt"):
        parse_device(device)


def _names(providers) -> list[str]:
    return [p for p, _ in providers]


def test_cpu_and_cuda_with_its_device_id():
    assert _providers("cpu", ALL) == [(CPU, {})]
    assert _providers("cuda", ALL) == [(CUDA, {"device_id": "0"}), (CPU, {})]
    assert _providers("cuda:1", ALL) == [(CUDA, {"device_id": "1"}), (CPU, {})]
    assert _providers("2", [CUDA, CPU]) == [(CUDA, {"device_id": "2"}), (CPU, {})]


def test_auto_takes_cuda_where_there_is_one():
    assert _names(_providers("auto", ALL)) == [CUDA, CPU]
    assert _providers("auto", [CPU]) == [(CPU, {})]


def test_tensorrt_first_then_cuda_for_what_it_leaves_then_the_cpu(tmp_path):
    profile = {"trt_profile_max_shapes": "images:32x3x640x640"}
    got = _providers("tensorrt:1", ALL, "fp16", tmp_path / "trt", profile)
    assert _names(got) == [TENSORRT, CUDA, CPU]
    trt = got[0][1]
    assert trt["device_id"] == "1" and got[1][1] == {"device_id": "1"}
    assert trt["trt_fp16_enable"] == "True"
    assert trt["trt_engine_cache_enable"] == "True"
    assert trt["trt_engine_cache_path"] == trt["trt_timing_cache_path"] == str(tmp_path / "trt")
    assert trt["trt_profile_max_shapes"] == "images:32x3x640x640"
    assert _providers("tensorrt", ALL)[0][1]["trt_fp16_enable"] == "False"


@pytest.mark.parametrize(
    ("device", "available", "message"),
    [
        ("cuda", [CPU], r"no CUDA provider \(available: CPUExecutionProvider\)"),
        ("cuda:1", [], r"no CUDA provider \(available: none\)"),
        ("tensorrt", [CUDA, CPU], r"no TensorRT provider \(available: CUDAExecutionProvider, CPU"),
        ("tensorrt:0", [CPU], "no TensorRT or CUDA provider"),
    ],
)
def test_a_missing_provider_names_what_there_is_and_the_package(device, available, message):
    with pytest.raises(ModelError, match=message) as e:
        _providers(device, available)
    assert "pip install onnxruntime-gpu" in str(e.value)


@pytest.mark.parametrize(
    ("device", "precision", "message"),
    [
        ("cuda", "fp16", "fp16 runs on TensorRT"),
        ("cpu", "fp16", "fp16 runs on TensorRT"),
        ("cpu", "bf16", "the onnx backend runs fp32, fp16, int8"),
    ],
)
def test_a_precision_the_device_cannot_run_is_refused(device, precision, message):
    with pytest.raises(ModelError, match=message):
        _providers(device, ALL, precision)


def test_the_tensorrt_profile_covers_every_batch_and_image_size():
    p = trt_profile("images", ["batch", 3, "height", "width"], 640, 16)
    assert p == {
        "trt_profile_min_shapes": "images:1x3x32x32",
        "trt_profile_opt_shapes": "images:8x3x640x640",
        "trt_profile_max_shapes": "images:16x3x640x640",
    }
    assert trt_profile("x", ["b", 3, 384, 640], 640, 4)["trt_profile_max_shapes"] == "x:4x3x384x640"
    assert trt_profile("x", [1, 3, 640, 640], 640, 32) == {}  # nothing dynamic: no profile
    with pytest.raises(ModelError, match=r"expected \(B, 3, H, W\)"):
        trt_profile("x", ["b", 3, 640], 640, 32)


class _FallingBack:
    """onnxruntime with GPU providers listed that do not start: every session runs on the CPU,
    as ONNX Runtime's own fallback does when CUDA's libraries or the GPU are missing."""

    def __init__(self, ort):
        self.ort, self.calls = ort, []

    def install(self, monkeypatch):
        real = self.ort.InferenceSession

        def session(path, options=None, providers=None, provider_options=None):
            self.calls.append(list(zip(providers, provider_options, strict=True)))
            return real(path, options, providers=[CPU])

        monkeypatch.setattr(self.ort, "get_available_providers", lambda: ALL)
        monkeypatch.setattr(self.ort, "InferenceSession", session)


@pytest.fixture(scope="module")
def model() -> Path:
    from stereopose.detection.models import default_onnx

    try:
        return default_onnx(export=False)
    except ModelError:
        pytest.skip("no ONNX pose model in the cache")


@pytest.fixture
def falling_back(monkeypatch, tmp_path) -> _FallingBack:
    import onnxruntime as ort

    monkeypatch.setenv("STEREOPOSE_CACHE", str(tmp_path / "cache"))  # the engines' folder
    fake = _FallingBack(ort)
    fake.install(monkeypatch)
    return fake


def test_a_gpu_that_did_not_start_is_an_error_not_a_silent_cpu(model, falling_back, tmp_path):
    with pytest.raises(ModelError, match=r"could not start its CUDA provider .*runs on CPU"):
        OnnxPoseDetector(model, device="cuda:1")
    assert falling_back.calls[-1][0] == (CUDA, {"device_id": "1"})
    with pytest.raises(ModelError, match=r"could not start its TensorRT .*TensorRT also needs"):
        OnnxPoseDetector(model, device="tensorrt", precision="fp16", max_batch=8)
    trt = dict(falling_back.calls[-1])[TENSORRT]
    assert trt["trt_profile_max_shapes"] == "images:8x3x640x640"
    engines = Path(trt["trt_engine_cache_path"])
    assert engines == tmp_path / "cache" / "models" / "trt" / "yolo11n-pose-fp16-640-b8"
    assert engines.is_dir()
    assert OnnxPoseDetector(model, device="auto").providers == [CPU]  # auto takes what there is


def test_what_this_onnx_runtime_cannot_run_is_a_clear_error(model):
    import onnxruntime as ort

    if TENSORRT in ort.get_available_providers():
        pytest.skip("this ONNX Runtime has TensorRT")
    with pytest.raises(ModelError, match="device 'tensorrt': this ONNX Runtime has no TensorRT"):
        make_detector("onnx", device="tensorrt")
    with pytest.raises(ModelError, match="fp16 needs the onnx backend"):
        make_detector("openvino", precision="fp16")
    with pytest.raises(ModelError, match="max_batch must be a positive integer"):
        OnnxPoseDetector(model, max_batch=0)


@pytest.fixture(scope="module")
def step() -> list[np.ndarray]:
    """One step of the real demo: its 4 cameras' frame 40."""
    return demo_step(40)


class _Counting:
    def __init__(self, session):
        self.session, self.batches = session, []

    def run(self, names, feeds):
        self.batches.append(len(next(iter(feeds.values()))))
        return self.session.run(names, feeds)


@pytest.mark.realdata
@pytest.mark.parametrize("max_batch", [32, 3])
def test_the_cameras_of_a_step_in_one_batch_find_what_one_at_a_time_finds(step, max_batch):
    det = make_detector("onnx", threads=1)
    assert det.batch_dynamic, "the cached ONNX model has a fixed batch"
    det.max_batch = max_batch
    one = [det.detect([im])[0] for im in step]
    det.session = counting = _Counting(det.session)
    batched = det.detect(step)
    assert counting.batches == ([4] if max_batch >= 4 else [3, 1])
    assert all(len(p) >= 1 for p in one)
    for a, b in zip(one, batched, strict=True):
        assert len(a) == len(b)
        np.testing.assert_allclose(a.boxes, b.boxes, atol=1e-2)
        np.testing.assert_allclose(a.keypoints, b.keypoints, atol=1e-2)
        np.testing.assert_allclose(a.scores, b.scores, atol=1e-4)


GPU_BENCHMARK = Path(__file__).resolve().parents[2] / "benchmarks" / "gpu.py"


def _gpu_benchmark(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, str(GPU_BENCHMARK), *args],
        capture_output=True,
        text=True,
        timeout=300,
        cwd=cwd,
    )


def test_the_gpu_benchmark_without_a_gpu_says_so_and_measures_nothing(tmp_path):
    import onnxruntime as ort

    if CUDA in ort.get_available_providers():
        pytest.skip("this ONNX Runtime has CUDA")
    done = _gpu_benchmark("--out", str(tmp_path), cwd=tmp_path)
    assert done.returncode == 2
    assert "no CUDA provider in this ONNX Runtime" in done.stderr
    assert "Traceback" not in done.stderr + done.stdout
    assert not list(tmp_path.iterdir())


@pytest.mark.realdata
@pytest.mark.slow
def test_the_gpu_benchmark_runs_its_measures_on_the_cpu(model, step, tmp_path):
    done = _gpu_benchmark(
        "--providers",
        "cpu",
        "--batches",
        "1,2",
        "--repeats",
        "1",
        "--steps",
        "1",
        "--out",
        str(tmp_path),
        cwd=tmp_path,
    )
    assert done.returncode == 0, done.stderr
    r = json.loads((tmp_path / "gpu.json").read_text())
    v = r["variants"]["cpu_fp32"]
    assert v["providers"] == [CPU] and list(v["batches"]) == ["1", "2"]
    assert v["batches"]["2"]["input"] == [2, 3, 640, 384]
    assert v["agreement"]["median_px"] == 0.0 and v["agreement"]["people_only_this"] == 0
    assert "| cpu fp32 |" in (tmp_path / "gpu.md").read_text()
