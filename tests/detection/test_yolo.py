"""The real detector on the real videos of Pose2Sim's multi-person demo (ONNX and ultralytics)."""

from __future__ import annotations

import json
import socket
from pathlib import Path

import numpy as np
import pytest

from stereopose.config import Config
from stereopose.detection import ModelError, make_detector
from stereopose.detection.openpose import read_pose_file
from stereopose.io.cameraset import CameraSet
from stereopose.pipeline import detect_videos, reconstruct_files

pytestmark = [pytest.mark.realdata, pytest.mark.slow]

CAMERAS = ("cam01", "cam02", "cam03", "cam04")


@pytest.fixture(scope="module")
def videos(pose2sim_dir: Path) -> list[Path]:
    return [pose2sim_dir / "Demo_MultiPerson" / "videos" / f"{c}.mp4" for c in CAMERAS]


@pytest.fixture(scope="module")
def onnx_detector():
    return make_detector("onnx")


@pytest.fixture(scope="module")
def detected(videos, onnx_detector, tmp_path_factory) -> tuple[Path, object]:
    """All 100 frames of the 4 videos through the ONNX backend."""
    out = tmp_path_factory.mktemp("pose")
    return out, detect_videos(videos, out, onnx_detector)


def _iou(a, b) -> float:
    w = max(0.0, min(a[2], b[2]) - max(a[0], b[0]))
    h = max(0.0, min(a[3], b[3]) - max(a[1], b[1]))
    inter = w * h
    return inter / ((a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - inter)


def test_files_in_the_openpose_layout_with_boxes_and_scores(detected):
    out, summary = detected
    assert summary.cameras == CAMERAS and summary.steps == 100
    assert all(summary.frames[c] == 100 for c in CAMERAS)
    first = json.loads((out / "cam01_json" / "cam01_000000000000_keypoints.json").read_text())
    person = first["people"][0]
    assert len(person["pose_keypoints_2d"]) == 51
    assert len(person["box_xyxy"]) == 4 and 0.25 < person["score"] <= 1


def test_two_main_people_found_in_95_percent_of_frames_of_every_camera(detected, shared_data_dir):
    """The main people are the two tallest boxes of the shared reference detections."""
    out, _ = detected
    for cam in CAMERAS:
        found = 0
        for frame in range(100):
            name = f"{cam}_json/{cam}_{frame:012d}_keypoints.json"
            r = read_pose_file(shared_data_dir / "pose" / name, cam, frame)
            o = read_pose_file(out / name, cam, frame)
            assert r.boxes is not None and o.boxes is not None
            tallest = np.argsort(r.boxes[:, 1] - r.boxes[:, 3])[:2]
            found += all(any(_iou(r.boxes[i], b) >= 0.5 for b in o.boxes) for i in tallest)
        assert found >= 95, f"{cam}: both main people found in {found} of 100 frames"


def test_detect_then_reconstruct_reprojects_within_8_px(detected, shared_data_dir, tmp_path):
    out, _ = detected
    summary = reconstruct_files(
        shared_data_dir / "calib.toml", out, tmp_path / "poses3d.jsonl", Config()
    )
    assert summary.frames == 100
    assert summary.median_confident_reprojection_px <= 8.0


def test_onnx_matches_ultralytics_to_a_tenth_of_a_pixel(videos, onnx_detector):
    ultra = make_detector("ultralytics")
    worst = 0.0
    with CameraSet(videos, max_frames=3) as cams:
        for step in cams:
            images = list(step.images.values())
            for a, b in zip(onnx_detector.detect(images), ultra.detect(images), strict=True):
                assert len(a) == len(b) > 0
                worst = max(
                    worst,
                    float(np.abs(a.keypoints[..., :2] - b.keypoints[..., :2]).max()),
                    float(np.abs(a.boxes - b.boxes).max()),
                )
                np.testing.assert_allclose(a.scores, b.scores, atol=1e-3)
                np.testing.assert_allclose(a.keypoints[..., 2], b.keypoints[..., 2], atol=1e-3)
    assert worst < 0.1


def test_detection_opens_no_network_socket(videos, monkeypatch):
    attempts: list[object] = []
    real_connect = socket.socket.connect

    def connect(self, address):
        if self.family in (socket.AF_INET, socket.AF_INET6):
            attempts.append(address)
            raise OSError("network access blocked by the test")
        return real_connect(self, address)

    def resolve(*args, **kwargs):
        attempts.append(args[:1])
        raise socket.gaierror("name resolution blocked by the test")

    monkeypatch.setattr(socket.socket, "connect", connect)
    monkeypatch.setattr(socket.socket, "connect_ex", connect)
    monkeypatch.setattr(socket, "getaddrinfo", resolve)
    monkeypatch.setattr(socket, "create_connection", lambda *a, **k: connect(socket.socket(), a))
    with CameraSet(videos[:2], max_frames=1) as cams:
        images = list(next(iter(cams)).images.values())
    for backend in ("onnx", "openvino", "ultralytics"):
        found = make_detector(backend).detect(images)
        assert all(len(p) >= 2 for p in found)
    assert attempts == []


def test_a_model_that_is_not_one_is_a_clear_error(tmp_path):
    bad = tmp_path / "broken.onnx"
    bad.write_bytes(b"not a model")
    with pytest.raises(ModelError, match=r"broken\.onnx"):
        make_detector("onnx", bad)
    with pytest.raises(ModelError, match="not found"):
        make_detector("ultralytics", tmp_path / "missing.pt")
    with pytest.raises(ModelError, match="multiple of 32"):
        make_detector("onnx", imgsz=500)
    with pytest.raises(ModelError, match="unknown detector backend"):
        make_detector("tensorrt")
