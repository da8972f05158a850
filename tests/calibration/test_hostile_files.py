"""Whatever a calibration file holds (native TOML, Qualisys XML, OpenCV YAML), loading it gives
a Rig whose every parameter is plausible, or a CalibrationError naming the file; never another
exception, never a crash."""

from __future__ import annotations

import copy
import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from test_qualisys import qca

from hostile import numbers, toml_text, values
from stereopose.calibration.formats import load_calibration
from stereopose.calibration.opencv_yaml import write_opencv_yaml
from stereopose.calibration.opencv_yaml_read import parse_yaml
from stereopose.checks import (
    MAX_DISTORTION,
    MAX_FOCAL_PX,
    MAX_IMAGE_PX,
    MAX_ROTATION_RAD,
    MAX_TRANSLATION_M,
)
from stereopose.errors import CalibrationError
from stereopose.sim.scene import make_rig
from stereopose.types import Rig

FUZZ = settings(
    max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
GOOD = {
    "name": "cam_a",
    "size": [1920.0, 1080.0],
    "matrix": [[1000.0, 0.0, 960.0], [0.0, 1000.0, 540.0], [0.0, 0.0, 1.0]],
    "distortions": [-0.1, 0.01, 0.0, 0.0],
    "rotation": [0.1, 0.2, 0.3],
    "translation": [0.5, -0.2, 4.0],
    "fisheye": False,
}
# (key, index into the value) -> name of the parameter in the error
PARAMETERS = {
    ("size", (0,)): "size width",
    ("size", (1,)): "size height",
    ("matrix", (0, 0)): "fx",
    ("matrix", (1, 1)): "fy",
    ("matrix", (0, 2)): "cx",
    ("matrix", (1, 2)): "cy",
    ("distortions", (0,)): "distortion k1",
    ("distortions", (3,)): "distortion p2",
    ("rotation", (0,)): "rotation rx",
    ("translation", (2,)): "translation tz",
}


def assert_plausible(rig: Rig) -> None:
    """The documented bounds, checked here independently of the code that enforces them."""
    for cam in rig:
        arrays = (cam.matrix, cam.distortions, cam.rotation, cam.translation, cam.size)
        assert all(np.isfinite(a).all() for a in arrays)
        assert all(1 <= s <= MAX_IMAGE_PX for s in cam.size)
        assert 0 < cam.matrix[0, 0] < MAX_FOCAL_PX and 0 < cam.matrix[1, 1] < MAX_FOCAL_PX
        assert np.abs(cam.distortions).max() < MAX_DISTORTION
        assert np.abs(cam.rotation).max() <= MAX_ROTATION_RAD
        assert np.abs(cam.translation).max() < MAX_TRANSLATION_M


def native(tmp_path: Path, *tables: dict[str, Any]) -> Path:
    path = tmp_path / "calib.toml"
    doc = {f"cam_{k}": t for k, t in enumerate(tables)}
    path.write_text(toml_text(doc), encoding="utf-8")
    return path


def with_value(key: str, index: tuple[int, ...], value: Any) -> dict[str, Any]:
    table = {k: (np.array(v).tolist() if isinstance(v, list) else v) for k, v in GOOD.items()}
    target = table[key]
    for i in index[:-1]:
        target = target[i]
    target[index[-1]] = value
    return table


@pytest.mark.parametrize(
    ("key", "index", "value"),
    [
        ("matrix", (0, 0), 1e308),
        ("matrix", (0, 0), 1e6),
        ("matrix", (1, 1), 1e7),
        ("matrix", (0, 2), 1e7),
        ("matrix", (1, 2), -1e6),
        ("distortions", (0,), 1e12),
        ("distortions", (3,), -1e3),
        ("rotation", (0,), 1e300),
        ("translation", (2,), 1e308),
        ("translation", (2,), -1e4),
        ("size", (0,), 1e9),
        ("size", (1,), 0.5),
    ],
)
def test_implausible_parameters_name_file_camera_parameter_and_value(
    tmp_path: Path, key: str, index: tuple[int, ...], value: float
) -> None:
    path = native(tmp_path, with_value(key, index, value), GOOD | {"name": "cam_b"})
    with pytest.raises(CalibrationError) as e:
        load_calibration(path)
    text = str(e.value)
    assert text.startswith(f"{path}: camera [cam_0]: "), text
    assert PARAMETERS[(key, index)] in text and text.endswith(f"got {float(value)!r}"), text


@pytest.mark.parametrize(
    ("key", "index", "value"),
    [
        ("matrix", (0, 0), 999_999.0),
        ("distortions", (0,), -999.0),
        ("translation", (0,), 9_999.0),
        ("size", (0,), 100_000.0),
        ("rotation", (2,), -100.0),
    ],
)
def test_values_just_inside_the_bounds_load(tmp_path, key, index, value) -> None:
    path = native(tmp_path, with_value(key, index, value), GOOD | {"name": "cam_b"})
    assert_plausible(load_calibration(path))


@st.composite
def camera_tables(draw) -> dict[str, Any]:
    """A good camera table with a few entries, or single numbers in them, made hostile."""
    table = copy.deepcopy(GOOD)
    for _ in range(draw(st.integers(0, 3))):
        key = draw(st.sampled_from(sorted(table)))
        if isinstance(table[key], list) and table[key] and draw(st.booleans()):
            row, i = table[key], draw(st.integers(0, len(table[key]) - 1))
            if isinstance(row[i], list) and row[i]:
                row, i = row[i], draw(st.integers(0, len(row[i]) - 1))
            row[i] = draw(numbers | values)
        else:
            table[key] = draw(values)
    return table


@FUZZ
@given(tables=st.lists(camera_tables(), min_size=1, max_size=3))
def test_native_files_load_plausibly_or_raise_calibration_error(tmp_path, tables) -> None:
    tables = [
        t | {"name": f"cam_{k}"} if isinstance(t.get("name"), str) else t
        for k, t in enumerate(tables)
    ]
    path = native(tmp_path, *tables)
    try:
        rig = load_calibration(path, min_cameras=1)
    except CalibrationError as e:
        assert str(e).startswith(f"{path}: "), str(e)
    else:
        assert_plausible(rig)


@FUZZ
@given(raw=st.binary(max_size=400))
def test_arbitrary_bytes_as_native_or_qualisys_file(tmp_path, raw: bytes) -> None:
    for name, head in (("calib.toml", b""), ("calib.qca.txt", b"<?xml version='1.0'?>")):
        path = tmp_path / name
        path.write_bytes(head + raw)
        try:
            assert_plausible(load_calibration(path, min_cameras=1))
        except CalibrationError as e:
            assert str(e).startswith(f"{path}: "), str(e)


ATTRIBUTES = re.compile(r'(\w+)="([^"]*)"')


@FUZZ
@given(data=st.data())
def test_qualisys_attributes_hostile_values(tmp_path, data) -> None:
    text = qca("cam1", "cam2")
    spans = [m.span(2) for m in ATTRIBUTES.finditer(text)]
    for _ in range(data.draw(st.integers(1, 3))):
        start, end = data.draw(st.sampled_from(spans))
        value = data.draw(
            st.sampled_from(["nan", "inf", "-inf", "1e999", "", "abc", "9" * 5000, "1e308"])
            | numbers.map(str)
        )
        text = text[:start] + value.ljust(end - start) + text[end:]
        spans = [m.span(2) for m in ATTRIBUTES.finditer(text)]
    path = tmp_path / "c.qca.txt"
    path.write_text(text)
    try:
        assert_plausible(load_calibration(path, min_cameras=1))
    except CalibrationError as e:
        assert str(e).startswith(f"{path}: "), str(e)


def test_qualisys_serials_of_any_length_sort_naturally(tmp_path: Path) -> None:
    path = tmp_path / "c.qca.txt"
    long = "cam" + "9" * 5000
    path.write_text(qca(long, "cam10", "cam2"))
    assert load_calibration(path).names == ("cam2", "cam10", long)


# OpenCV YAML


@pytest.fixture(scope="module")
def yaml_files(tmp_path_factory) -> tuple[bytes, bytes]:
    folder = tmp_path_factory.mktemp("yml")
    intri, extri = write_opencv_yaml(folder, make_rig(2, np.random.default_rng(1)))
    return intri.read_bytes(), extri.read_bytes()


def _load_yaml(folder: Path, intri: bytes, extri: bytes) -> None:
    folder.mkdir(exist_ok=True)
    (folder / "intri.yml").write_bytes(intri)
    (folder / "extri.yml").write_bytes(extri)
    try:
        assert_plausible(load_calibration(folder, min_cameras=1))
    except CalibrationError as e:
        assert str(e).startswith(str(folder)), str(e)


INSERTS = [
    b"[",
    b"]",
    b"{",
    b"!!opencv-matrix",
    b".nan",
    b"1e999",
    b":",
    b"\n  ",
    b"- ",
    b"\x00",
    b"'",
    b'"',
    b"%YAML:1.0\n",
    b"&a",
    b"*a",
    b"#",
    b"\t",
    b"\xff",
    b",",
    b"\n",
]


@FUZZ
@given(data=st.data())
def test_mutated_opencv_yaml_never_crashes(tmp_path, yaml_files, data) -> None:
    # cv2.FileStorage aborted the process (heap corruption) on files like these
    files = [bytearray(yaml_files[0]), bytearray(yaml_files[1])]
    for _ in range(data.draw(st.integers(1, 8))):
        b = files[data.draw(st.integers(0, 1))]
        at = data.draw(st.integers(0, len(b) - 1))
        op = data.draw(st.integers(0, 2))
        if op == 0:
            b[at] = data.draw(st.integers(0, 255))
        elif op == 1:
            del b[at : at + data.draw(st.integers(1, 40))]
        else:
            b[at:at] = data.draw(st.sampled_from(INSERTS))
    _load_yaml(tmp_path / "yml", bytes(files[0]), bytes(files[1]))


@FUZZ
@given(intri=st.binary(max_size=300), extri=st.binary(max_size=300))
def test_arbitrary_bytes_as_opencv_yaml(tmp_path, intri: bytes, extri: bytes) -> None:
    _load_yaml(tmp_path / "yml", intri, extri)


@pytest.mark.parametrize(
    ("old", "new", "message"),
    [
        ("H_cam01: 1080", "H_cam01: .nan", r"intri\.yml: `H_cam01`: expected .*, got nan"),
        ("W_cam01: 1920", "W_cam01: 1e999", r"`W_cam01`: expected .*, got inf"),
        ("W_cam01: 1920", "W_cam01: -3", r"`W_cam01`: expected .*, got -3"),
        ("W_cam01: 1920", "W_cam01: wide", r"`W_cam01`: expected a number, got 'wide'"),
        ("rows: 3", "rows: 4", r"`K_cam01`: rows x cols = 4 x 3 but data holds 9"),
        ("names:", "names: 7\nnames_:", r"no `names` list"),
        ("K_cam02", "K_cam01", r"line \d+: `K_cam01` appears twice"),
        ("data: [", "data: [[", r"nested lists"),
    ],
)
def test_bad_opencv_yaml_values_name_the_file_key_and_value(
    tmp_path, yaml_files, old: str, new: str, message: str
) -> None:
    intri = yaml_files[0].decode().replace(old, new, 1).encode()
    folder = tmp_path / "yml"
    folder.mkdir()
    (folder / "intri.yml").write_bytes(intri)
    (folder / "extri.yml").write_bytes(yaml_files[1])
    with pytest.raises(CalibrationError, match=message):
        load_calibration(folder)


def test_the_yaml_reader_reads_what_opencv_writes() -> None:
    # OpenCV 3/4 header, comments, quoted names, a flow list over lines, a matrix block
    text = """%YAML:1.0
---
# cameras
names: [ "1", 'it''s' ]   # two
K_1: !!opencv-matrix
   rows: 3
   cols: 3
   dt: d
   data: [ 1., 0., 2.,
       0., 1., .Nan ]
W_1: -.inf
"""
    doc = parse_yaml(text, "x.yml")
    assert doc["names"] == ["1", "it's"]
    assert doc["K_1"] == {
        "rows": "3",
        "cols": "3",
        "dt": "d",
        "data": ["1.", "0.", "2.", "0.", "1.", ".Nan"],
    }
    assert doc["W_1"] == "-.inf"
