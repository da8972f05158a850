"""The detector chosen by itself (backend = "auto", the default): OpenVINO bf16 where the CPU
has bfloat16 instructions, ONNX Runtime fp32 (exact) where it has not or OpenVINO is missing;
an explicit backend or precision honoured as written; the choice said and kept."""

from __future__ import annotations

from pathlib import Path

import pytest

from stereopose.config import Config
from stereopose.detection import ModelError, choose, cpu_bf16, make_detector
from stereopose.detection.int8_choice import MIN_SPEEDUP, Int8Found

NO_INT8 = Int8Found(None, None, None)  # no INT8 model made: the float choices alone
PASSED = {"accepted": True, "p95_px": 3.1, "p95_bound_px": 6.0}


def test_the_default_is_auto() -> None:
    d = Config().detector
    assert (d.backend, d.precision) == ("auto", "auto")


@pytest.mark.parametrize(
    ("bf16", "backend", "precision", "says"),
    [
        (True, "openvino", "bf16", "bfloat16 instructions"),
        (False, "onnx", "fp32", "no bfloat16 instructions on this CPU"),
        (None, "onnx", "fp32", "OpenVINO not installed"),
    ],
)
def test_auto_takes_bf16_where_the_cpu_has_it_and_an_exact_backend_elsewhere(
    bf16, backend, precision, says
) -> None:
    c = choose(bf16=bf16, int8=NO_INT8)
    assert (c.backend, c.precision) == (backend, precision)
    assert says in c.why and c.why.startswith("auto")


@pytest.mark.parametrize(
    ("args", "expected"),
    [
        (("onnx", "auto"), ("onnx", "fp32")),  # a backend named runs fp32, as it always did
        (("openvino", "auto"), ("openvino", "fp32")),
        (("openvino", "bf16"), ("openvino", "bf16")),
        (("ultralytics", "auto"), ("ultralytics", "fp32")),
        (("auto", "fp32"), ("onnx", "fp32")),  # fp32 asked for: exact
        (("auto", "int8"), ("onnx", "int8")),
    ],
)
def test_what_is_named_is_honoured(args, expected) -> None:
    for bf16 in (True, False):
        fast = Int8Found(Path("m.xml"), PASSED, 3.0)  # never taken when a precision is named
        c = choose(*args, bf16=bf16, int8=fast)
        assert (c.backend, c.precision) == expected


def test_a_device_picks_the_backend_that_runs_on_it() -> None:
    assert choose(device="cuda:0", bf16=True).backend == "onnx"
    assert choose(device="tensorrt", bf16=True).backend == "onnx"
    assert choose(device="gpu.1", bf16=True).backend == "openvino"


def test_bf16_asked_for_where_there_is_none_is_a_clear_error() -> None:
    with pytest.raises(ModelError, match="no bfloat16 instructions"):
        choose(precision="bf16", bf16=False)
    with pytest.raises(ModelError, match="needs OpenVINO"):
        choose(precision="bf16", bf16=None)


@pytest.mark.parametrize(
    ("bf16", "found", "expected", "says"),
    [
        # faster and checked: taken, on either CPU that has OpenVINO
        (True, Int8Found(Path("m.xml"), PASSED, 1.6), ("openvino", "int8"), "1.60x OpenVINO bf16"),
        (False, Int8Found(Path("m.xml"), PASSED, 1.6), ("openvino", "int8"), "1.60x fp32"),
        # a CPU where it does not pay: the float model, and why
        (True, Int8Found(Path("m.xml"), PASSED, 1.05), ("openvino", "bf16"), "1.05x"),
        (False, Int8Found(Path("m.xml"), PASSED, 0.8), ("onnx", "fp32"), f"under {MIN_SPEEDUP}x"),
        # not within the bound, or never weighed here
        (
            True,
            Int8Found(Path("m.xml"), {"accepted": False, "p95_px": 17.4, "p95_bound_px": 6.0}, 2),
            ("openvino", "bf16"),
            "17.4 px (p95) from fp32's, over the 6.0 px bound",
        ),
        (True, Int8Found(Path("m.xml"), PASSED, None), ("openvino", "bf16"), "not be measured"),
        (True, NO_INT8, ("openvino", "bf16"), "no INT8 model made"),
        # no OpenVINO: nothing to run it with
        (None, Int8Found(Path("m.xml"), PASSED, 3.0), ("onnx", "fp32"), "OpenVINO not installed"),
    ],
)
def test_auto_takes_openvinos_int8_model_only_where_it_is_checked_and_faster(
    bf16, found, expected, says
) -> None:
    c = choose(bf16=bf16, int8=found)
    assert (c.backend, c.precision) == expected
    assert says in c.why and c.why.startswith("auto"), c.why
    if expected[1] != "int8" and bf16 is not None:
        assert "INT8 not taken" in c.why


@pytest.mark.realdata
def test_the_detector_made_says_what_it_runs_and_why() -> None:
    det = make_detector(threads=1)
    here = cpu_bf16()
    if det.choice.precision == "int8":  # OpenVINO's INT8 model, checked and faster here
        assert det.choice.backend == "openvino" and "INT8 model runs at" in det.choice.why
    elif here:
        assert (det.choice.backend, det.choice.precision) == ("openvino", "bf16")
        assert det.runs_in == "bf16"  # what OpenVINO compiled it to
    else:
        assert (det.choice.backend, det.choice.precision) == ("onnx", "fp32")
    assert det.choice.as_dict()["why"].startswith("auto")
    named = make_detector("onnx", threads=1)
    assert named.choice.as_dict() == {
        "backend": "onnx",
        "precision": "fp32",
        "why": "as configured",
    }
