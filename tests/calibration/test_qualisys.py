from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from stereopose.calibration import load_calibration, read_qca
from stereopose.errors import CalibrationError

CAMERA = """  <camera active="1" serial="{serial}">
      <fov_video bottom="1919" left="{left}" right="1087" top="0"/>
      <transform r11="1" r12="0" r13="0" r21="0" r22="1" r23="0" r31="0" r32="0" r33="1"
        x="100.0" y="-2000.0" z="1500.0"/>
      <intrinsic centerPointU="34110.316406" centerPointV="60680.792969"
        focalLengthU="107599.671875" focalLengthV="107588.828125" radialDistortion1="-0.046183"
        radialDistortion2="0.139983" radialDistortion3="0.0" tangentalDistortion1="0.000608"
        tangentalDistortion2="0.00069"/>
    </camera>
"""


def qca(*serials: str, left: int = 0) -> str:
    cams = "".join(CAMERA.format(serial=s, left=left) for s in serials)
    head = "<?xml version='1.0' encoding='ASCII'?>\n<calibration>\n<cameras>\n"
    return f"{head}{cams}</cameras>\n</calibration>\n"


def test_synthetic_conversion(tmp_path: Path) -> None:
    path = tmp_path / "Calib.qca.txt"
    path.write_text(qca("cam10", "cam2", "cam1", left=8))
    rig = read_qca(path)
    assert rig.names == ("cam1", "cam2", "cam10")  # natural order
    cam = rig[0]
    assert cam.size == (1080.0, 1920.0)
    np.testing.assert_allclose(
        cam.matrix,
        [
            [107599.671875 / 64, 0, 34110.316406 / 64 - 8],
            [0, 107588.828125 / 64, 60680.792969 / 64],
            [0, 0, 1],
        ],
    )
    np.testing.assert_allclose(
        cam.distortions, np.array([-0.046183, 0.139983, 0.000608, 0.00069]) / 64
    )
    # Qualisys' camera looks along -z with y up; OpenCV's along +z with y down.
    np.testing.assert_allclose(cam.R, np.diag([1.0, -1.0, -1.0]), atol=1e-12)
    np.testing.assert_allclose(cam.center, [0.1, -2.0, 1.5], atol=1e-12)


def test_load_calibration_dispatches_on_name_and_content(tmp_path: Path) -> None:
    by_name = tmp_path / "Calib.qca.txt"
    by_name.write_text(qca("a", "b"))
    by_content = tmp_path / "calib.xml"
    by_content.write_text(qca("a", "b"))
    assert load_calibration(by_name).names == load_calibration(by_content).names == ("a", "b")
    one = tmp_path / "one.qca.txt"
    one.write_text(qca("a"))
    with pytest.raises(
        CalibrationError, match=re.escape(str(one)) + ": .*needs at least 2 cameras, found 1"
    ):
        load_calibration(one)
    assert load_calibration(one, min_cameras=1).names == ("a",)


def remove_attr(text: str, attr: str) -> str:
    out, n = re.subn(rf'\s{attr}="[^"]*"', "", text, count=1)
    assert n == 1
    return out


BAD = [
    ("not xml", "this is not xml", r"not a valid Qualisys XML file"),
    (
        "no cameras",
        "<?xml version='1.0'?><calibration><cameras/></calibration>",
        r"no <cameras>/<camera>",
    ),
    ("no serial", remove_attr(qca("cam01", "cam02"), "serial"), r"camera #1: missing 'serial'"),
    (
        "no focal",
        remove_attr(qca("cam01", "cam02"), "focalLengthU"),
        r"camera 'cam01': <intrinsic> lacks attributes: focalLengthU",
    ),
    (
        "no fov",
        qca("cam01", "cam02").replace("fov_video", "fov_other", 1),
        r"camera 'cam01': missing <fov_video> element",
    ),
    (
        "text number",
        qca("cam01", "cam02").replace('r11="1"', 'r11="one"', 1),
        r"camera 'cam01': <transform> attribute r11='one' is not a number",
    ),
    (
        "nan",
        qca("cam01", "cam02").replace('x="100.0"', 'x="nan"', 1),
        r"camera 'cam01': <transform> attribute x is nan",
    ),
    (
        "not a rotation",
        qca("cam01", "cam02").replace('r11="1"', 'r11="2"', 1),
        r"camera 'cam01': <transform> r11..r33 is not a rotation matrix",
    ),
    (
        "zero focal",
        qca("cam01", "cam02").replace('focalLengthV="107588.828125"', 'focalLengthV="0"', 1),
        r"camera 'cam01': focal lengths must be positive",
    ),
    ("duplicate", qca("cam01", "cam01"), r"camera 'cam01': duplicate serial"),
]


@pytest.mark.parametrize(("case", "text", "message"), BAD, ids=[c[0] for c in BAD])
def test_malformed_qca(tmp_path: Path, case: str, text: str, message: str) -> None:
    path = tmp_path / "Calib.qca.txt"
    path.write_text(text)
    with pytest.raises(CalibrationError, match=re.escape(str(path)) + ".*" + message):
        load_calibration(path)


def test_missing_qca(tmp_path: Path) -> None:
    path = tmp_path / "Calib.qca.txt"
    with pytest.raises(
        CalibrationError, match=re.escape(str(path)) + ": calibration file not found"
    ):
        read_qca(path)


@pytest.mark.realdata
def test_demo_qca_matches_the_shared_calibration(pose2sim_dir: Path, shared_data_dir: Path) -> None:
    rig = load_calibration(pose2sim_dir / "Demo_MultiPerson" / "calibration" / "Calib.qca.txt")
    ref = load_calibration(shared_data_dir / "calib.toml")
    assert rig.names == ref.names == ("cam01", "cam02", "cam03", "cam04")
    for cam, expected in zip(rig, ref, strict=True):
        assert cam.size == expected.size
        assert cam.fisheye == expected.fisheye
        for attr in ("matrix", "distortions", "rotation", "translation"):
            np.testing.assert_allclose(
                getattr(cam, attr), getattr(expected, attr), rtol=0, atol=1e-9
            )
