"""Calibration runs whose outputs fail after the work: the result is kept, never lost."""

from __future__ import annotations

import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from stereopose.calibration.formats import load_calibration
from stereopose.errors import OutputError
from stereopose.pipeline.calibrate import calibrate_intrinsics_dir, check_calibration_outputs


@pytest.fixture
def photos(tmp_path: Path, rendered) -> Path:
    folder = tmp_path / "int_cam07_img"
    folder.mkdir()
    for k, img in enumerate(rendered[0][:5]):  # enough for intrinsics, quick to detect
        cv2.imwrite(str(folder / f"{k:02d}.png"), img)
    return folder


def _turn_into_a_file(folder: Path) -> None:
    """The folder vanishes and a file takes its place (as after the checks, mid-run)."""
    shutil.rmtree(folder)
    folder.write_text("")


@pytest.mark.slow  # a whole intrinsics calibration: a few seconds
def test_an_output_folder_gone_at_the_end_keeps_the_calibration(
    photos: Path, tmp_path: Path, board, camera
) -> None:
    out = tmp_path / "calib" / "intrinsics.toml"
    run = calibrate_intrinsics_dir(
        photos, board, out, on_camera=lambda name: _turn_into_a_file(out.parent)
    )
    assert list(run.failures) == [str(out)] and run.calibration is None
    assert "is a file, not a folder" in run.failures[str(out)]
    try:
        kept = load_calibration(run.kept, min_cameras=1)
    finally:
        run.kept.unlink()
    assert kept.names == (camera.name,)
    np.testing.assert_allclose(kept[0].matrix, run.results[camera.name].camera.matrix)


@pytest.mark.slow
def test_a_report_folder_gone_at_the_end_still_writes_the_calibration(
    photos: Path, tmp_path: Path, board
) -> None:
    out, report = tmp_path / "intrinsics.toml", tmp_path / "report"
    run = calibrate_intrinsics_dir(
        photos, board, out, report_dir=report, on_camera=lambda name: _turn_into_a_file(report)
    )
    assert run.calibration == out and run.outputs == [out] and run.kept is None
    assert list(run.failures) == [str(report / "intrinsics.png")]
    load_calibration(out, min_cameras=1)


def test_outputs_are_checked_before_the_work(tmp_path: Path) -> None:
    (tmp_path / "file").write_text("")
    (tmp_path / "folder.toml").mkdir()
    check_calibration_outputs(tmp_path / "new" / "c.toml", tmp_path / "new" / "report")
    check_calibration_outputs(tmp_path / "yaml_folder", None)
    for out, report in (
        (tmp_path / "file" / "c.toml", None),
        (tmp_path / "folder.toml", None),
        (tmp_path / "c.toml", tmp_path / "file"),
        (tmp_path / "file" / "intri.yml", None),
    ):
        with pytest.raises(OutputError, match="cannot write the"):
            check_calibration_outputs(out, report)
