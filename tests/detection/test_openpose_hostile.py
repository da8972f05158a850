"""Hostile keypoint files: only a logged skip or a KeypointsError, never a hang or a crash."""

from __future__ import annotations

import json
import logging
import math
import os
import tempfile
import threading
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from stereopose.detection.openpose import (
    MAX_COORD_PX,
    MAX_FILE_BYTES,
    MAX_FRAME,
    MAX_PEOPLE_PER_VIEW,
    read_pose_dir,
    read_pose_file,
)
from stereopose.errors import KeypointsError
from stereopose.types import People2D
from waiting import wait_until

FUZZ = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def person(seed: int = 0) -> list[float]:
    rng = np.random.default_rng(seed)
    kp = np.column_stack([rng.uniform(0, 1000, (17, 2)), rng.uniform(0.1, 1, 17)])
    return [round(float(v), 3) for v in kp.ravel()]


def kp_file(pose_dir: Path, cam: str, frame: int) -> Path:
    path = pose_dir / f"{cam}_json" / f"{cam}_{frame:012d}_keypoints.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    return path


def good_dir(tmp_path: Path, frames: int = 3) -> Path:
    for f in range(frames):
        for cam in ("a", "b"):
            kp_file(tmp_path, cam, f).write_text(
                json.dumps({"people": [{"pose_keypoints_2d": person(f)}]})
            )
    return tmp_path


def check_people(people: People2D) -> None:
    """What the rest of the pipeline may rely on, whatever the file held."""
    kp = people.keypoints
    assert kp.ndim == 3 and kp.shape[1:] == (17, 3) and len(kp) <= MAX_PEOPLE_PER_VIEW
    seen = kp[..., 2] > 0
    assert np.isfinite(kp[seen]).all() and (kp[..., 2] <= 1).all()
    assert (np.abs(kp[seen][:, :2]) <= MAX_COORD_PX).all()
    assert np.isnan(kp[~seen][:, :2]).all()
    if people.boxes is not None:
        assert np.isfinite(people.boxes).all()


def read_or_refuse(raw: bytes) -> None:
    """Reading `raw` as a keypoint file gives people or a KeypointsError naming the file."""
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "cam_000000000001_keypoints.json"
        path.write_bytes(raw)
        try:
            people = read_pose_file(path, "cam", 1)
        except KeypointsError as e:
            assert str(e).startswith(str(path))
            return
        check_people(people)


json_values = st.recursive(
    st.none()
    | st.booleans()
    | st.integers()
    | st.integers(min_value=-(10**400), max_value=10**400)
    | st.floats(allow_nan=True, allow_infinity=True)
    | st.text(max_size=5),
    lambda inner: st.lists(inner, max_size=6) | st.dictionaries(st.text(max_size=5), inner),
    max_leaves=30,
)
numbers = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.integers(min_value=-(10**30), max_value=10**30),
    st.none(),
)


def dumps(doc: object) -> bytes:
    return json.dumps(doc, allow_nan=True).encode()  # NaN, Infinity literals as Python writes


@FUZZ
@given(st.binary(max_size=300))
def test_arbitrary_bytes(raw: bytes) -> None:
    read_or_refuse(raw)


@FUZZ
@given(json_values)
def test_arbitrary_json(doc: object) -> None:
    read_or_refuse(dumps(doc))
    read_or_refuse(dumps({"people": doc}))
    read_or_refuse(dumps({"people": [{"pose_keypoints_2d": doc, "box_xyxy": doc}]}))


@FUZZ
@given(
    st.lists(st.lists(numbers | json_values, min_size=0, max_size=60), max_size=4),
    st.lists(numbers, min_size=4, max_size=4) | json_values,
    numbers | json_values,
)
def test_arbitrary_people(people: list[list], box: object, score: object) -> None:
    doc = {"people": [{"pose_keypoints_2d": p, "box_xyxy": box, "score": score} for p in people]}
    read_or_refuse(dumps(doc))


@FUZZ
@given(st.lists(numbers, min_size=51, max_size=51), st.lists(numbers, min_size=4, max_size=4))
def test_any_numbers_give_sane_people(values: list, box: list) -> None:
    """Negative, infinite, huge coordinates and confidences outside [0, 1]."""
    read_or_refuse(dumps({"people": [{"pose_keypoints_2d": values, "box_xyxy": box}]}))


@pytest.mark.parametrize(
    ("text", "problem"),
    [
        ("[" * 100_000 + "]" * 100_000, "nested too deeply"),
        ('{"people": ' + "[" * 5_000 + "]" * 5_000 + "}", "nested too deeply"),
        ('{"people": [{"pose_keypoints_2d": [' + "9" * 5_000 + "]}]}", "too many digits"),
        ('{"people": [{"pose_keypoints_2d": [' + "1e999," * 50 + "1]}]}", None),
    ],
    ids=["nested", "nested people", "huge integer", "overflowing floats"],
)
def test_nesting_and_huge_numbers(tmp_path: Path, text: str, problem: str | None) -> None:
    path = kp_file(tmp_path, "a", 0)
    path.write_text(text)
    if problem is None:  # 1e999 is infinity: every joint missing, the file still read
        assert (read_pose_file(path, "a", 0).keypoints[..., 2] == 0).all()
        return
    with pytest.raises(KeypointsError, match=problem):
        read_pose_file(path, "a", 0)


def test_huge_score_and_box_are_dropped_not_fatal(tmp_path: Path) -> None:
    path = kp_file(tmp_path, "a", 0)
    rec = '{"pose_keypoints_2d": %s, "score": %s, "box_xyxy": [Infinity, 0, 1, 1]}'
    path.write_text('{"people": [%s]}' % (rec % (json.dumps(person(0)), "9" * 400)))
    people = read_pose_file(path, "a", 0)
    assert len(people) == 1 and people.scores is None and people.boxes is None


def test_far_joints_are_missing(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    values = person(0)
    values[0:3] = [-1e300, 5.0, 0.9]
    values[3:6] = [2 * MAX_COORD_PX, 5.0, 0.9]
    values[6:9] = [10.0, 5.0, 7.5]  # confidence above 1: clipped
    path = kp_file(tmp_path, "a", 0)
    path.write_text(json.dumps({"people": [{"pose_keypoints_2d": values}]}))
    with caplog.at_level(logging.WARNING):
        kp = read_pose_file(path, "a", 0).keypoints
    assert (kp[0, :2, 2] == 0).all() and np.isnan(kp[0, :2, :2]).all()
    assert kp[0, 2, 2] == 1.0
    assert "2 joint(s)" in caplog.text and path.name in caplog.text


def test_too_many_people_in_one_view(tmp_path: Path) -> None:
    path = kp_file(tmp_path, "a", 0)
    crowd = [{"pose_keypoints_2d": person(0)}] * MAX_PEOPLE_PER_VIEW
    path.write_text(json.dumps({"people": crowd}))
    assert len(read_pose_file(path, "a", 0)) == MAX_PEOPLE_PER_VIEW
    path.write_text(json.dumps({"people": [*crowd, crowd[0]]}))
    with pytest.raises(KeypointsError, match=f"{MAX_PEOPLE_PER_VIEW + 1} people in one camera"):
        read_pose_file(path, "a", 0)


def test_oversized_file_is_refused_unread(tmp_path: Path) -> None:
    path = kp_file(tmp_path, "a", 0)
    with open(path, "wb") as f:
        f.truncate(MAX_FILE_BYTES + 1)  # sparse: no time spent writing it
    with pytest.raises(KeypointsError, match="too large for a keypoint file"):
        read_pose_file(path, "a", 0)


def in_thread(fn) -> dict:
    """Run fn in a thread; wait (with a deadline) for it to end; its result or error."""
    out: dict = {}

    def target() -> None:
        try:
            out["value"] = fn()
        except BaseException as e:  # reported to the test
            out["error"] = e

    th = threading.Thread(target=target, daemon=True)
    th.start()
    wait_until(lambda: not th.is_alive(), "the reader to return", timeout_s=10)
    return out


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="named pipes need POSIX")
def test_named_pipe_neither_blocks_nor_aborts(tmp_path: Path, caplog) -> None:
    good_dir(tmp_path)
    fifo = kp_file(tmp_path, "a", 7)
    os.mkfifo(fifo)
    with caplog.at_level(logging.WARNING):
        seq = in_thread(lambda: read_pose_dir(tmp_path, ["a", "b"]))["value"]
    assert seq.frames == [0, 1, 2]
    assert seq.skipped == [(fifo, "a named pipe, not a keypoint file")]
    assert fifo.name in caplog.text
    # a pipe that takes a regular file's place after the folder was listed
    swapped = kp_file(tmp_path, "a", 1)
    swapped.unlink()
    os.mkfifo(swapped)
    frames = in_thread(lambda: dict(seq))["value"]
    assert set(frames[1]) == {"b"} and set(frames[0]) == {"a", "b"}
    assert seq.skipped[-1] == (swapped, "a named pipe, not a keypoint file")
    assert seq.skipped_per_camera == {"a": 2}


def test_folder_and_device_named_like_keypoint_files(tmp_path: Path) -> None:
    good_dir(tmp_path)
    kp_file(tmp_path, "a", 8).mkdir()
    dev = kp_file(tmp_path, "b", 9)
    if Path("/dev/zero").exists():
        dev.symlink_to("/dev/zero")
    broken = kp_file(tmp_path, "b", 10)
    broken.symlink_to(tmp_path / "nowhere")
    seq = read_pose_dir(tmp_path, ["a", "b"])
    assert seq.frames == [0, 1, 2]
    reasons = {p.name: why for p, why in seq.skipped}
    assert reasons[kp_file(tmp_path, "a", 8).name] == "a folder, not a keypoint file"
    assert reasons[broken.name] == "a broken link, not a keypoint file"
    if dev.is_symlink():
        assert reasons[dev.name] == "a device, not a keypoint file"
        with pytest.raises(KeypointsError, match="a device"):
            read_pose_file(dev, "b", 9)


def test_frame_number_beyond_the_limit(tmp_path: Path) -> None:
    good_dir(tmp_path)
    far = tmp_path / "a_json" / f"a_{MAX_FRAME + 1}_keypoints.json"
    far.write_text('{"people": []}')
    ok = tmp_path / "a_json" / f"a_{MAX_FRAME}_keypoints.json"
    ok.write_text('{"people": []}')
    seq = read_pose_dir(tmp_path, ["a", "b"])
    assert seq.frames == [0, 1, 2, MAX_FRAME]
    assert [(p, "beyond" in why) for p, why in seq.skipped] == [(far, True)]


def test_empty_camera_folder_is_reported(tmp_path: Path, caplog) -> None:
    good_dir(tmp_path)
    (tmp_path / "c_json").mkdir()
    with caplog.at_level(logging.WARNING):
        seq = read_pose_dir(tmp_path, ["a", "b", "c"])
    assert seq.cameras == ("a", "b")
    assert "camera c: no keypoint files" in caplog.text


def test_no_camera_with_files_is_an_error(tmp_path: Path) -> None:
    for cam in ("a", "b"):
        (tmp_path / f"{cam}_json").mkdir()
    (tmp_path / "a_json" / "notes.txt").write_text("")
    with pytest.raises(KeypointsError, match=r"no keypoint files .*a \(a_json\), b \(b_json\)"):
        read_pose_dir(tmp_path, ["a", "b"])


def test_non_finite_literals_never_reach_the_pipeline(tmp_path: Path) -> None:
    path = kp_file(tmp_path, "a", 0)
    values = [math.inf, -math.inf, math.nan] * 17
    path.write_text(json.dumps({"people": [{"pose_keypoints_2d": values}]}))
    kp = read_pose_file(path, "a", 0).keypoints
    assert (kp[..., 2] == 0).all() and np.isnan(kp[..., :2]).all()
