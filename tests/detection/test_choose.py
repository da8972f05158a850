"""The detector chosen by itself (backend = "auto", the default): OpenVINO bf16 where the CPU
has bfloat16 instructions, ONNX Runtime fp32 (exact) where it has not or OpenVINO is missing;
an explicit backend or precision honoured as written; the choice said and kept."""

from __future__ import annotations

import pytest

from stereopose.config import Config
from stereopose.detection import ModelError, choose, cpu_bf16, make_detector


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
    c = choose(bf16=bf16)
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
        c = choose(*args, bf16=bf16)
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


@pytest.mark.realdata
def test_the_detector_made_says_what_it_runs_and_why() -> None:
    det = make_detector(threads=1)
    here = cpu_bf16()
    if here:
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
