"""Intrinsics from rendered and real checkerboard photos; bad input."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from stereopose.calibration.board import Board
from stereopose.calibration.intrinsics import (
    calibrate_intrinsics,
    camera_name,
    detect_all,
    iter_images,
)
from stereopose.errors import CalibrationError


def write_photos(folder: Path, images) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    for k, img in enumerate(images):
        cv2.imwrite(str(folder / f"photo_{k:02d}.png"), img)
    return folder


def test_rendered_photos_give_the_camera(tmp_path: Path, rendered, board, camera) -> None:
    folder = write_photos(tmp_path / "int_cam07_img", rendered[0])
    (folder / "broken.jpg").write_bytes(b"not an image")
    cv2.imwrite(str(folder / "blank.png"), np.full((720, 1280), 200, np.uint8))
    dets = detect_all(iter_images(folder), board)
    result = calibrate_intrinsics(camera_name(folder.name), dets, board)
    K = result.camera.matrix
    assert result.camera.name == "cam07"
    assert K[0, 0] == pytest.approx(900.0, rel=0.005) and K[1, 1] == pytest.approx(905.0, rel=0.005)
    assert K[0, 2] == pytest.approx(650.0, abs=5) and K[1, 2] == pytest.approx(350.0, abs=5)
    assert result.camera.distortions[:2] == pytest.approx([-0.25, 0.08], abs=0.02)
    assert result.rms_px < 0.3 and len(result.used) == 12
    assert result.rejected == {"blank.png": "no 9x6 board found", "broken.jpg": "unreadable image"}
    assert 0.0 < result.coverage <= 1.0


def test_a_photo_with_misplaced_corners_is_rejected(rendered, board) -> None:
    dets = detect_all(((f"p{k}", img) for k, img in enumerate(rendered[0])), board)
    bad = dets[3].corners
    shifted = bad.points.copy()
    shifted += np.random.default_rng(1).normal(0, 3.0, shifted.shape)  # badly placed corners
    dets[3].corners = type(bad)(shifted, bad.method, bad.fit_px, bad.square_px)
    result = calibrate_intrinsics("c", dets, board)
    assert "p3" in result.rejected and "reprojection error" in result.rejected["p3"]
    assert result.camera.matrix[0, 0] == pytest.approx(900.0, rel=0.005)


@pytest.mark.slow
def test_no_board_anywhere_or_one_photo_is_a_clear_error(tmp_path: Path, rendered, board) -> None:
    blank = write_photos(tmp_path / "blank", [np.full((720, 1280), 128, np.uint8)] * 3)
    with pytest.raises(CalibrationError, match=r"found in 0 of 3 photo\(s\).*board size"):
        calibrate_intrinsics("c", detect_all(iter_images(blank), board), board)
    wrong = Board(7, 5, 0.08)
    with pytest.raises(CalibrationError, match="7x5 board was found in 0"):
        calibrate_intrinsics(
            "c",
            detect_all(iter_images(write_photos(tmp_path / "w", rendered[0][:4])), wrong),
            wrong,
        )
    single = write_photos(tmp_path / "one", rendered[0][:1])
    with pytest.raises(CalibrationError, match="found in 1 of 1"):
        calibrate_intrinsics("c", detect_all(iter_images(single), board), board)
    with pytest.raises(CalibrationError, match="no photos"):
        list(iter_images(tmp_path / "empty" if (tmp_path / "empty").mkdir() is None else tmp_path))


def test_video_frames_are_sampled(tmp_path: Path, rendered, board) -> None:
    path = tmp_path / "cam07.avi"
    vw = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10.0, (1280, 720), False)
    for img in rendered[0][:6]:
        for _ in range(5):
            vw.write(img)
    vw.release()
    frames = list(iter_images(path, every_s=0.5))
    assert len(frames) == 6 and all(f is not None for _, f in frames)
    broken = tmp_path / "broken.mp4"
    broken.write_bytes(b"\x00" * 100)
    with pytest.raises(CalibrationError, match=r"broken\.mp4"):
        list(iter_images(broken))


@pytest.mark.slow
@pytest.mark.realdata
def test_real_photos_match_the_qualisys_calibration(pose2sim_dir: Path) -> None:
    folder = pose2sim_dir / "Demo_SinglePerson" / "calibration" / "intrinsics"
    qualisys_fx = {"cam01": 1681.2, "cam02": 1673.7, "cam03": 1681.6, "cam04": 1675.2}
    board = Board(4, 7, 0.06)
    for sub in sorted(folder.iterdir()):
        name = camera_name(sub.name)
        dets = detect_all(iter_images(sub), board)
        assert sum(d.corners is not None for d in dets) >= 6, name
        result = calibrate_intrinsics(name, dets, board)
        assert result.camera.matrix[0, 0] == pytest.approx(qualisys_fx[name], rel=0.01), name
