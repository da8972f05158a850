"""OpenVINO's INT8 model (NNCF): made from real frames and checked against fp32 on others, its
check kept beside it and true, its speed here measured once and kept, and the auto choice
taking it only where the check passed and it is faster."""

from __future__ import annotations

import json

import pytest

from stereopose.detection import choose
from stereopose.detection.int8_choice import MIN_SPEEDUP, SPEED_FILE, Int8Found, speedup
from stereopose.detection.int8_openvino import (
    CHECK_MISSED,
    CHECK_P95_PX,
    RECIPE,
    check,
    current,
    quantize_int8_openvino,
    read_check,
)
from stereopose.detection.models import (
    OV_CHECK_FRAMES,
    calibration_frames,
    default_onnx,
    int8_videos,
)
from stereopose.detection.openvino_core import ov_core

pytest.importorskip("openvino")
pytest.importorskip("nncf")

pytestmark = [pytest.mark.realdata, pytest.mark.slow]


@pytest.fixture(scope="module")
def made(tmp_path_factory):
    """The INT8 model made here from the cache's ONNX model (as `models export` does)."""
    out = tmp_path_factory.mktemp("int8") / "yolo11n-pose-int8.xml"
    return quantize_int8_openvino(default_onnx(), out)


def test_the_model_and_its_check_are_written_together(made):
    assert made.is_file() and made.with_suffix(".bin").is_file()
    found = read_check(made)
    assert found is not None and found["model"] == default_onnx().name
    assert found["frames"] == OV_CHECK_FRAMES and found["joints"] > 300
    # the verdict is the bound's, as written
    within = found["p95_px"] <= CHECK_P95_PX and found["missed"] <= CHECK_MISSED * found["people"]
    assert found["accepted"] is within and found["p95_bound_px"] == CHECK_P95_PX
    # a model folder left half-written is never taken: no .xml without its check
    assert not list(made.parent.glob(".int8.*"))


def test_each_silu_is_left_whole_so_that_it_fuses_into_its_convolution(made):
    """Quantisers at the convolutions' inputs, none inside x * sigmoid(x): a quantised
    sigmoid or product keeps OpenVINO from fusing the activation into the convolution."""
    model = ov_core().read_model(str(made))
    fq = [op for op in model.get_ops() if op.get_type_name() == "FakeQuantize"]
    assert len(fq) > 40  # the backbone and neck are quantised
    silu = [op for op in model.get_ops() if op.get_friendly_name().endswith("/act/Mul")]
    assert len(silu) > 40
    for op in silu:
        for value in op.input_values():
            assert value.get_node().get_type_name() != "FakeQuantize", op.get_friendly_name()
    # its check says how it was made; a model made otherwise is made again
    assert read_check(made)["recipe"] == RECIPE and current(made)


def test_a_model_made_by_an_older_recipe_is_stale(made, tmp_path, monkeypatch, capsys):
    old = tmp_path / made.name
    old.write_bytes(made.read_bytes())
    old.with_suffix(".bin").write_bytes(made.with_suffix(".bin").read_bytes())
    found = read_check(made)
    found.pop("recipe")
    old.with_suffix(".json").write_text(json.dumps(found))
    assert not current(old)
    monkeypatch.setattr("stereopose.detection.models.openvino_int8_path", lambda *a: old)
    from stereopose.detection.int8_choice import find_int8

    stale = find_int8("fp32", measure=False)
    assert stale.stale and "older recipe" in (stale.refusal("fp32") or "")
    c = choose(bf16=True, int8=stale)
    assert c.precision == "bf16" and "older recipe" in c.why
    # `models export` makes it again, and says why; then it is current and kept as it is
    from stereopose.cli import main

    args = ["models", "export", "--openvino-int8", "--out", str(old)]
    assert main(args) == 0
    assert "made by an older recipe, made again" in capsys.readouterr().out
    assert current(old) and read_check(old)["recipe"] == RECIPE
    made_at = old.stat().st_mtime_ns
    assert main(args) == 0 and old.stat().st_mtime_ns == made_at
    assert "older recipe" not in capsys.readouterr().out


def test_it_finds_the_people_fp32_finds_on_real_frames_it_was_not_made_from(made):
    from stereopose.detection.yolo_openvino import OpenVinoPoseDetector

    frames = calibration_frames(int8_videos(), 8, phase=0.25)
    ref = OpenVinoPoseDetector(default_onnx(), precision="fp32", threads=2)
    int8 = OpenVinoPoseDetector(made, precision="int8", threads=2)
    # its float layers (the pose head) in bfloat16 where the CPU has it, else in fp32
    caps = ov_core().get_property("CPU", "OPTIMIZATION_CAPABILITIES")
    assert int8.runs_in == ("bf16" if "BF16" in caps else "f32")
    found = check(ref, int8, frames)
    # the same people, each joint where fp32 puts it to a few pixels in most of them (the
    # tail, p95, is what the check bounds: benchmarks/results/backends.md)
    assert found["people"] >= 8 and found["missed"] == 0 and found["extra"] == 0
    assert found["median_px"] < 4.0


def test_its_speed_is_measured_once_per_machine_and_weighed_by_auto(made, monkeypatch, tmp_path):
    first = speedup(made, "fp32")
    assert first is not None and first > 0
    kept = json.loads((made.parent / SPEED_FILE).read_text())
    assert list(kept.values()) == [pytest.approx(first, abs=1e-3)]
    # asked again: the kept figure, nothing measured
    monkeypatch.setattr("stereopose.detection.int8_choice._measure", _never)
    assert speedup(made, "fp32") == pytest.approx(first, abs=1e-3)
    found = Int8Found(made, read_check(made), first)
    c = choose(bf16=False, int8=found)
    if found.check["accepted"] and first >= MIN_SPEEDUP:
        assert (c.backend, c.precision) == ("openvino", "int8")
    else:  # over the bound, or not faster here: fp32, and why
        assert (c.backend, c.precision) == ("onnx", "fp32") and "INT8 not taken" in c.why


def test_a_model_without_its_check_is_not_taken(made, tmp_path):
    bare = tmp_path / made.name
    bare.write_bytes(made.read_bytes())
    bare.with_suffix(".bin").write_bytes(made.with_suffix(".bin").read_bytes())
    found = Int8Found(bare, read_check(bare), 3.0)
    c = choose(bf16=True, int8=found)
    assert c.precision == "bf16" and "no passed check" in c.why


def _never(*_args, **_kwargs):
    raise AssertionError("measured again")
