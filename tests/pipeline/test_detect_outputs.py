"""`detect` whose keypoint files cannot be written for one camera: the others go on, exit 3."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from stereopose.cli import main
from stereopose.detection.models import default_onnx


@pytest.fixture(scope="module")
def model() -> Path:
    try:
        return default_onnx()
    except Exception as e:  # the cache is filled by `make install`
        pytest.skip(f"no exported model in the cache: {e}")


def _images(folder: Path, n: int = 3) -> Path:
    folder.mkdir()
    for i in range(n):
        cv2.imwrite(str(folder / f"{i:03d}.png"), np.full((96, 128, 3), 120, np.uint8))
    return folder


def test_a_camera_whose_files_fail_is_named_and_the_others_are_written(
    tmp_path: Path, model: Path, capsys
) -> None:
    a, b = _images(tmp_path / "a"), _images(tmp_path / "b")
    out = tmp_path / "out"
    out.mkdir()
    (out / "b_json").symlink_to("/dev/full")  # camera b's folder cannot be made
    code = main(["detect", "--videos", str(a), str(b), "--out", str(out), "--imgsz", "320"])
    captured = capsys.readouterr()
    printed = captured.out + captured.err
    assert code == 3
    assert len(list((out / "a_json").glob("*_keypoints.json"))) == 3
    assert "1 output could not be written" in printed and "b_json" in printed
    assert "Traceback" not in printed
