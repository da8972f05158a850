from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from stereopose.calibration.formats import load_calibration, save_calibration
from stereopose.errors import CalibrationError
from stereopose.types import Camera, Rig


def random_rig(rng: np.random.Generator, n: int = 3) -> Rig:
    cams = []
    for i in range(n):
        f = rng.uniform(800, 2000)
        cams.append(
            Camera(
                name=f"cam_{i + 1:02d}",
                size=(1920.0, 1080.0),
                matrix=np.array(
                    [
                        [f, 0.0, rng.uniform(900, 1000)],
                        [0.0, f * 1.001, rng.uniform(500, 580)],
                        [0, 0, 1],
                    ]
                ),
                distortions=rng.normal(0, 0.01, 4 + i % 2),
                rotation=rng.normal(0, 1, 3),
                translation=rng.normal(0, 3, 3),
                fisheye=i == 2,
            )
        )
    return Rig(tuple(cams))


def assert_same_rig(a: Rig, b: Rig) -> None:
    assert a.names == b.names
    for ca, cb in zip(a, b, strict=True):
        assert ca.size == cb.size
        assert ca.fisheye == cb.fisheye
        for attr in ("matrix", "distortions", "rotation", "translation"):
            np.testing.assert_array_equal(getattr(ca, attr), getattr(cb, attr))


def test_round_trip_is_bit_exact(tmp_path: Path) -> None:
    rig = random_rig(np.random.default_rng(0))
    path = tmp_path / "calib.toml"
    save_calibration(path, rig, {"adjusted": False, "error": 0.123, "n": 3, "note": 'a "b"'})
    assert_same_rig(load_calibration(path), rig)
    assert not [p for p in tmp_path.iterdir() if p.name != "calib.toml"]  # no temp file left


def test_written_text_follows_the_contract(tmp_path: Path) -> None:
    rig = random_rig(np.random.default_rng(1), 2)
    path = tmp_path / "calib.toml"
    save_calibration(path, rig, {"adjusted": True})
    text = path.read_text()
    assert text.startswith('[cam_01]\nname = "cam_01"\nsize = [ 1920.0, 1080.0]\nmatrix = [ [ ')
    keys = re.findall(r"^(\w+) =", text, flags=re.M)
    fields = ["name", "size", "matrix", "distortions", "rotation", "translation", "fisheye"]
    assert keys == fields * 2 + ["adjusted"]
    assert text.rstrip().endswith("[metadata]\nadjusted = true")


def test_names_that_are_not_bare_keys_are_quoted(tmp_path: Path) -> None:
    rig = random_rig(np.random.default_rng(2), 2)
    rig = Rig(
        tuple(
            Camera(n, c.size, c.matrix, c.distortions, c.rotation, c.translation)
            for n, c in zip(["front door", "pannéau.2"], rig, strict=True)
        )
    )
    path = tmp_path / "calib.toml"
    save_calibration(path, rig)
    assert '["front door"]' in path.read_text(encoding="utf-8")
    assert load_calibration(path).names == ("front door", "pannéau.2")


def test_metadata_tables_are_ignored_and_name_falls_back_to_key(tmp_path: Path) -> None:
    rig = random_rig(np.random.default_rng(3), 2)
    path = tmp_path / "calib.toml"
    save_calibration(path, rig, {"error": 0.5})
    text = path.read_text().replace('name = "cam_02"\n', "")
    path.write_text("[other]\nx = 1\n" + text)
    assert load_calibration(path).names == ("cam_01", "cam_02")


def test_rotation_matrix_is_accepted(tmp_path: Path) -> None:
    path = tmp_path / "calib.toml"
    save_calibration(path, random_rig(np.random.default_rng(4), 2))
    text = path.read_text().replace(
        "rotation = [ ",
        "rotation = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]\nxx = [ ",
        1,
    )
    path.write_text(text)
    np.testing.assert_array_equal(load_calibration(path)[0].rotation, np.zeros(3))


GOOD = """[cam_a]
name = "cam_a"
size = [ 1920.0, 1080.0]
matrix = [ [ 1000.0, 0.0, 960.0], [ 0.0, 1000.0, 540.0], [ 0.0, 0.0, 1.0]]
distortions = [ 0.0, 0.0, 0.0, 0.0]
rotation = [ 0.1, 0.2, 0.3]
translation = [ 0.0, 0.0, 3.0]
fisheye = false

[cam_b]
name = "cam_b"
size = [ 1920.0, 1080.0]
matrix = [ [ 1000.0, 0.0, 960.0], [ 0.0, 1000.0, 540.0], [ 0.0, 0.0, 1.0]]
distortions = [ 0.0, 0.0, 0.0, 0.0]
rotation = [ 0.1, -0.2, 0.3]
translation = [ 1.0, 0.0, 3.0]
fisheye = false

[metadata]
adjusted = false
"""


def first_cam(old: str, new: str) -> str:
    head, sep, tail = GOOD.partition("[cam_b]")
    assert old in head
    return head.replace(old, new, 1) + sep + tail


BAD_FILES = [
    (
        "toml syntax",
        GOOD.replace("size = [ 1920.0, 1080.0]", "size = [ 1920.0, ", 1),
        r"not valid TOML: .*\(at line 4, column 1\)",
    ),
    (
        "missing keys",
        first_cam("size = [ 1920.0, 1080.0]\n", "").replace("rotation = [ 0.1, 0.2, 0.3]\n", ""),
        r"\[cam_a\]: missing keys: size, rotation",
    ),
    (
        "matrix shape",
        first_cam("[ 0.0, 0.0, 1.0]]", "]"),
        r"\[cam_a\]: matrix must have shape \(3, 3\), got \(2, 3\)",
    ),
    (
        "ragged matrix",
        first_cam("[ 0.0, 0.0, 1.0]]", "[ 0.0, 1.0]]"),
        r"\[cam_a\]: matrix must have shape \(3, 3\), got ragged",
    ),
    (
        "distortion count",
        first_cam("distortions = [ 0.0, 0.0, 0.0, 0.0]", "distortions = [ 0.0]"),
        r"\[cam_a\]: distortions must have shape \(4,\) or \(5,\), got \(1,\)",
    ),
    (
        "string number",
        first_cam("translation = [ 0.0, 0.0, 3.0]", 'translation = [ 0.0, "0", 3.0]'),
        r"\[cam_a\]: translation must contain only numbers, found '0'",
    ),
    (
        "bool number",
        first_cam("size = [ 1920.0, 1080.0]", "size = [ true, 1080.0]"),
        r"\[cam_a\]: size must contain only numbers, found True",
    ),
    (
        "not a list",
        first_cam("rotation = [ 0.1, 0.2, 0.3]", 'rotation = "identity"'),
        r"\[cam_a\]: rotation must contain only numbers, found 'identity'",
    ),
    (
        "nan",
        first_cam("rotation = [ 0.1, 0.2, 0.3]", "rotation = [ nan, 0.2, 0.3]"),
        r"\[cam_a\]: rotation contains NaN or infinite",
    ),
    (
        "inf",
        first_cam("translation = [ 0.0, 0.0, 3.0]", "translation = [ 0.0, 0.0, inf]"),
        r"\[cam_a\]: translation contains NaN or infinite",
    ),
    (
        "not a rotation",
        first_cam("rotation = [ 0.1, 0.2, 0.3]", "rotation = [[1, 0, 0], [0, 1, 0], [0, 0, 2]]"),
        r"\[cam_a\]: camera 'cam_a': rotation is not a rotation matrix",
    ),
    (
        "reflection",
        first_cam("rotation = [ 0.1, 0.2, 0.3]", "rotation = [[1, 0, 0], [0, 1, 0], [0, 0, -1]]"),
        r"\[cam_a\]: camera 'cam_a': rotation is not a rotation matrix",
    ),
    (
        "zero focal",
        first_cam("[ [ 1000.0,", "[ [ 0.0,"),
        r"\[cam_a\]: focal lengths must be positive, got fx=0.0",
    ),
    (
        "negative focal",
        first_cam("[ 0.0, 1000.0, 540.0]", "[ 0.0, -5.0, 540.0]"),
        r"\[cam_a\]: focal lengths must be positive.*fy=-5.0",
    ),
    (
        "bad K layout",
        first_cam("[ 0.0, 0.0, 1.0]]", "[ 0.0, 0.0, 2.0]]"),
        r"\[cam_a\]: camera 'cam_a': matrix must be",
    ),
    (
        "negative size",
        first_cam("size = [ 1920.0, 1080.0]", "size = [ -1920.0, 1080.0]"),
        r"\[cam_a\]: camera 'cam_a': size must be positive",
    ),
    (
        "empty name",
        first_cam('name = "cam_a"', 'name = ""'),
        r"\[cam_a\]: name must be a non-empty",
    ),
    (
        "fisheye",
        first_cam("fisheye = false", 'fisheye = "no"'),
        r"\[cam_a\]: fisheye must be true or false",
    ),
    (
        "duplicate names",
        GOOD.replace('name = "cam_b"', 'name = "cam_a"'),
        r"\[cam_b\]: duplicate camera name 'cam_a' \(also used by table \[cam_a\]\)",
    ),
    ("one camera", GOOD.partition("[cam_b]")[0], r"needs at least 2 cameras, found 1 \(cam_a\)"),
    ("no camera", "[metadata]\nadjusted = false\n", r"no camera tables found.*\[metadata\]"),
]


@pytest.mark.parametrize(("case", "text", "message"), BAD_FILES, ids=[c[0] for c in BAD_FILES])
def test_bad_files_name_the_file_camera_and_problem(
    tmp_path: Path, case: str, text: str, message: str
) -> None:
    path = tmp_path / "calib.toml"
    path.write_text(text)
    with pytest.raises(CalibrationError, match=re.escape(str(path)) + ".*" + message):
        load_calibration(path)


def test_good_text_loads(tmp_path: Path) -> None:
    path = tmp_path / "calib.toml"
    path.write_text(GOOD)
    rig = load_calibration(path)
    assert rig.names == ("cam_a", "cam_b")
    assert load_calibration(path.with_name("calib.toml"), min_cameras=1).names == rig.names


def test_min_cameras_is_a_parameter(tmp_path: Path) -> None:
    path = tmp_path / "calib.toml"
    path.write_text(GOOD.partition("[cam_b]")[0])
    assert load_calibration(path, min_cameras=1).names == ("cam_a",)


def _missing(p: Path) -> Path:
    return p


def _directory(p: Path) -> Path:
    p.mkdir()
    return p


def _latin1(p: Path) -> Path:
    p.write_bytes(b'[cam]\nname = "\xff"\n')
    return p


@pytest.mark.parametrize(
    ("make", "message"),
    [
        (_missing, "calibration file not found"),
        (_directory, "cannot read calibration file"),
        (_latin1, "not UTF-8"),
    ],
    ids=["missing", "directory", "not utf-8"],
)
def test_unreadable_files(tmp_path: Path, make, message: str) -> None:
    path = make(tmp_path / "calib.toml")
    with pytest.raises(CalibrationError, match=re.escape(str(path)) + ".*" + message):
        load_calibration(path)


def test_metadata_values_must_be_simple(tmp_path: Path) -> None:
    rig = random_rig(np.random.default_rng(5), 2)
    with pytest.raises(CalibrationError, match="metadata 'bad'"):
        save_calibration(tmp_path / "calib.toml", rig, {"bad": [1, 2]})
    assert not list(tmp_path.iterdir())
