from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np
import pytest

from stereopose.detection.openpose import (
    find_camera_dirs,
    frame_number,
    read_pose_dir,
    write_pose_frame,
)
from stereopose.errors import KeypointsError
from stereopose.skeleton import NUM_JOINTS
from stereopose.types import People2D


def person(seed: int = 0) -> list[float]:
    rng = np.random.default_rng(seed)
    kp = np.column_stack([rng.uniform(0, 1000, (NUM_JOINTS, 2)), rng.uniform(0.1, 1, NUM_JOINTS)])
    return [round(float(v), 3) for v in kp.ravel()]


def write_json(path: Path, doc: object) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(doc))
    return path


def kp_file(pose_dir: Path, cam: str, frame: int) -> Path:
    return pose_dir / f"{cam}_json" / f"{cam}_{frame:012d}_keypoints.json"


@pytest.mark.parametrize(
    ("name", "expected"),
    [
        ("cam_01_000000000042_keypoints.json", 42),
        ("cam01_000000000000_keypoints.json", 0),
        ("frame7.json", 7),
        ("12_cam3_0099.json", 99),
        ("keypoints.json", None),
    ],
)
def test_frame_number(name: str, expected: int | None) -> None:
    assert frame_number(name) == expected


def test_find_camera_dirs(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    for d in ("cam_a_json", "cam_b", "other_json"):
        (tmp_path / d).mkdir()
    with caplog.at_level(logging.INFO):
        dirs = find_camera_dirs(tmp_path, ["cam_a", "cam_b", "cam_c"])
    assert dirs == {"cam_a": tmp_path / "cam_a_json", "cam_b": tmp_path / "cam_b"}
    assert "cam_c_json" in caplog.text and "other_json" in caplog.text


def test_find_camera_dirs_without_any_match(tmp_path: Path) -> None:
    (tmp_path / "foo_json").mkdir()
    with pytest.raises(
        KeypointsError, match=r"no keypoint folder.*cam1_json, cam2_json; found foo_json"
    ):
        find_camera_dirs(tmp_path, ["cam1", "cam2"])
    with pytest.raises(KeypointsError, match="keypoints folder not found"):
        find_camera_dirs(tmp_path / "nope", ["cam1"])


def test_index_and_read(tmp_path: Path) -> None:
    for f in (0, 1, 2):
        write_json(kp_file(tmp_path, "a", f), {"people": [{"pose_keypoints_2d": person(f)}]})
    for f in (1, 3):
        write_json(kp_file(tmp_path, "b", f), {"people": []})
    (tmp_path / "a_json" / "notes.txt").write_text("not keypoints")
    seq = read_pose_dir(tmp_path, ["b", "a"])
    assert seq.cameras == ("b", "a")
    assert seq.frames == [0, 1, 2, 3] and len(seq) == 4
    assert set(seq.frame(0)) == {"a"}
    f1 = seq.frame(1)
    assert len(f1["a"]) == 1 and len(f1["b"]) == 0
    assert f1["a"].frame == 1 and f1["a"].camera == "a"
    np.testing.assert_allclose(f1["a"].keypoints.ravel(), person(1))
    assert [n for n, _ in seq] == [0, 1, 2, 3]
    assert seq.skipped == []


def test_nulls_boxes_and_scores(tmp_path: Path) -> None:
    kp = person(0)
    kp[0:3] = [None, None, None]
    kp[5] = None  # conf of joint 1
    doc = {
        "people": [
            {"pose_keypoints_2d": kp, "box_xyxy": [1, 2, 3, 4], "score": 0.9},
            {"pose_keypoints_2d": person(1), "box_xyxy": [5, 6, 7, 8], "score": 0.5},
        ]
    }
    write_json(kp_file(tmp_path, "a", 5), doc)
    people = read_pose_dir(tmp_path, ["a"]).frame(5)["a"]
    assert np.isnan(people.keypoints[0, :2, :2]).all()
    assert (people.keypoints[0, :2, 2] == 0).all()
    np.testing.assert_array_equal(people.boxes, [[1, 2, 3, 4], [5, 6, 7, 8]])
    np.testing.assert_array_equal(people.scores, [0.9, 0.5])


def test_boxes_dropped_unless_every_person_has_one(tmp_path: Path) -> None:
    doc = {
        "people": [
            {"pose_keypoints_2d": person(0), "box_xyxy": [1, 2, 3, 4], "score": 0.9},
            {"pose_keypoints_2d": person(1)},
        ]
    }
    write_json(kp_file(tmp_path, "a", 0), doc)
    people = read_pose_dir(tmp_path, ["a"]).frame(0)["a"]
    assert len(people) == 2 and people.boxes is None and people.scores is None


def test_person_with_wrong_length_is_skipped(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    doc = {"people": [{"pose_keypoints_2d": person(0)[:-3]}, {"pose_keypoints_2d": person(1)}]}
    path = write_json(kp_file(tmp_path, "a", 0), doc)
    with caplog.at_level(logging.WARNING):
        people = read_pose_dir(tmp_path, ["a"]).frame(0)["a"]
    assert len(people) == 1
    np.testing.assert_allclose(people.keypoints.ravel(), person(1))
    assert path.name in caplog.text and "person 0" in caplog.text and "got 48" in caplog.text


BAD_FILES = [
    ("bad json", "{ not json", "not valid JSON"),
    ("not an object", "[1, 2]", "expected a JSON object, got list"),
    ("no people", '{"version": 1.3}', "missing key 'people'"),
    ("people not a list", '{"people": {}}', "'people' must be a list, got dict"),
    ("person not an object", '{"people": [3]}', "person 0 must be an object"),
    (
        "no keypoints",
        '{"people": [{"score": 1}]}',
        "pose_keypoints_2d must be a list of 51 numbers",
    ),
    (
        "keypoints text",
        '{"people": [{"pose_keypoints_2d": "x"}]}',
        "must be a list of 51 numbers, got str",
    ),
    (
        "keypoint not a number",
        json.dumps({"people": [{"pose_keypoints_2d": ["a", *person(0)[1:]]}]}),
        "must hold numbers or null, found 'a'",
    ),
    (
        "keypoint a boolean",
        json.dumps({"people": [{"pose_keypoints_2d": [*person(0)[:50], True]}]}),
        "must hold numbers or null, found True",
    ),
    (
        "keypoint a list",
        json.dumps({"people": [{"pose_keypoints_2d": [[1.0], *person(0)[1:]]}]}),
        "must hold numbers or null, found [1.0]",
    ),
    (
        "keypoint too large",
        json.dumps({"people": [{"pose_keypoints_2d": [10**400, *person(0)[1:]]}]}),
        "too large for a float",
    ),
    ("empty file", "", "not valid JSON"),
    ("byte order mark", "\ufeff" + json.dumps({"people": []}), "not valid JSON"),
]


@pytest.mark.parametrize(("case", "text", "problem"), BAD_FILES, ids=[c[0] for c in BAD_FILES])
def test_malformed_file_is_skipped_and_logged(
    tmp_path: Path, caplog: pytest.LogCaptureFixture, case: str, text: str, problem: str
) -> None:
    for f in range(3):
        write_json(kp_file(tmp_path, "a", f), {"people": [{"pose_keypoints_2d": person(f)}]})
        write_json(kp_file(tmp_path, "b", f), {"people": []})
    bad = kp_file(tmp_path, "a", 1)
    bad.write_text(text)
    seq = read_pose_dir(tmp_path, ["a", "b"])
    with caplog.at_level(logging.WARNING):
        frames = dict(seq)
    assert set(frames[1]) == {"b"}  # camera a has no frame 1
    assert set(frames[0]) == set(frames[2]) == {"a", "b"}
    np.testing.assert_allclose(frames[2]["a"].keypoints.ravel(), person(2))
    assert bad.name in caplog.text and problem in caplog.text
    assert len(seq.skipped) == 1
    assert seq.skipped[0][0] == bad and problem in seq.skipped[0][1]
    assert set(seq.frame(1)) == {"b"} and len(seq.skipped) == 1  # logged once


def test_nan_and_infinity_literals_read_as_missing(tmp_path: Path) -> None:
    # not JSON, but Python's json writes them; such files are read as before
    values = ["NaN", "NaN", "0", "Infinity", *map(str, person(0)[4:])]
    path = kp_file(tmp_path, "a", 0)
    path.parent.mkdir(parents=True)
    path.write_text('{"people": [{"pose_keypoints_2d": [' + ", ".join(values) + "]}]}")
    people = read_pose_dir(tmp_path, ["a"]).frame(0)["a"]
    assert np.isnan(people.keypoints[0, :2, :2]).all() and (people.keypoints[0, :2, 2] == 0).all()
    np.testing.assert_allclose(people.keypoints.ravel()[6:], person(0)[6:])


def test_two_files_for_one_frame(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    first = write_json(tmp_path / "a_json" / "a_0007_keypoints.json", {"people": []})
    second = write_json(tmp_path / "a_json" / "a_000000000007_keypoints.json", {"people": []})
    with caplog.at_level(logging.WARNING):
        seq = read_pose_dir(tmp_path, ["a"])
    assert seq.frames == [7]
    kept = min(first, second, key=lambda p: p.name)
    assert seq.files("a") == {7: kept}
    assert len(seq.skipped) == 1 and "frame 7 already read" in seq.skipped[0][1]
    assert "frame 7" in caplog.text


def test_write_read_round_trip(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    kp = np.concatenate(
        [rng.uniform(0, 1000, (2, NUM_JOINTS, 2)), rng.uniform(0.1, 1, (2, NUM_JOINTS, 1))], -1
    )
    kp[0, 3] = np.nan
    kp[1, 5:8, :2] = np.nan
    people = People2D("cam 1", 42, kp, boxes=rng.uniform(0, 100, (2, 4)), scores=[0.8, 0.7])
    path = write_pose_frame(tmp_path, "cam 1", people)
    assert path == tmp_path / "cam 1_json" / "cam 1_000000000042_keypoints.json"
    doc = json.loads(path.read_text())
    assert doc["version"] == 1.3 and doc["people"][0]["person_id"] == [-1]
    assert doc["people"][0]["pose_keypoints_2d"][9:12] == [0, 0, 0]
    back = read_pose_dir(tmp_path, ["cam 1"]).frame(42)["cam 1"]
    np.testing.assert_array_equal(back.keypoints, people.keypoints)
    np.testing.assert_array_equal(back.boxes, people.boxes)
    np.testing.assert_array_equal(back.scores, people.scores)
    empty = write_pose_frame(tmp_path, "cam 1", People2D.empty("cam 1", 43))
    assert json.loads(empty.read_text())["people"] == []
    assert len(read_pose_dir(tmp_path, ["cam 1"]).frame(43)["cam 1"]) == 0


@pytest.mark.realdata
def test_shared_pose_dir(shared_data_dir: Path) -> None:
    seq = read_pose_dir(shared_data_dir / "pose", ["cam01", "cam02", "cam03", "cam04"])
    assert seq.cameras == ("cam01", "cam02", "cam03", "cam04")
    assert seq.frames == list(range(100))
    counts = []
    for _, frame in seq:
        assert set(frame) == set(seq.cameras)
        counts.append(sum(len(p) for p in frame.values()))
        for people in frame.values():
            assert people.boxes is not None and people.scores is not None
    assert min(counts) > 0 and seq.skipped == []
