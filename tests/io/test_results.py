"""3D poses JSON lines: the contract, null joints, reading back, bad files."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from stereopose.errors import StereoposeError
from stereopose.io.results import PosesWriter, floor_position, load_people3d, read_poses
from stereopose.types import People3D


def people(frame: int) -> People3D:
    J = np.arange(2 * 17 * 3, dtype=float).reshape(2, 17, 3) / 10
    J[0, 3] = np.nan  # a joint not reconstructed
    conf = np.full((2, 17), 0.9)
    conf[0, 3] = 0.0
    return People3D(
        frame,
        J,
        conf,
        np.array([4, 7]),
        np.full((2, 17), 1.5),
        np.full((2, 17), 3),
        np.array([[0, 1], [1, -1]]),
    )


def test_writer_follows_the_contract(tmp_path: Path) -> None:
    out = tmp_path / "sub" / "poses.jsonl"
    with PosesWriter(out, fps=25.0) as w:
        w.write(people(0))
        w.write(People3D.empty(1, 2))
        w.write(people(2))
    lines = [json.loads(line) for line in out.read_text().splitlines()]
    assert [r["frame"] for r in lines] == [0, 1, 2]
    assert lines[1] == {"frame": 1, "t": 0.04, "people": []}
    p0 = lines[0]["people"][0]
    assert p0["id"] == 4 and len(p0["joints"]) == 17 and p0["joints"][3] is None
    assert p0["joints"][0] == [0.0, 0.1, 0.2]
    assert p0["conf"][3] == 0.0 and p0["views"][0] == 3
    assert p0["position"] == pytest.approx([(3.3 + 3.6) / 2, (3.4 + 3.7) / 2])


def test_read_back(tmp_path: Path) -> None:
    out = tmp_path / "poses.jsonl"
    with PosesWriter(out, fps=10.0) as w:
        w.write(people(5))
    [(frame, t, ppl)] = list(read_poses(out))
    assert frame == 5 and t == pytest.approx(0.5)
    np.testing.assert_allclose(ppl[0]["joints_array"], people(5).joints[0], atol=1e-4)


@pytest.mark.parametrize(
    ("content", "message"),
    [("{not json\n", r"poses\.jsonl:1: malformed"), ('{"people": []}\n', r":1: malformed.*frame")],
)
def test_malformed_file_names_the_line(tmp_path: Path, content: str, message: str) -> None:
    out = tmp_path / "poses.jsonl"
    out.write_text(content)
    with pytest.raises(StereoposeError, match=message):
        list(read_poses(out))


def test_unwritable_output_is_a_clear_error(tmp_path: Path) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("")
    with pytest.raises(StereoposeError, match="cannot write 3D poses"):
        PosesWriter(blocker / "poses.jsonl", fps=25.0)


def test_floor_position_falls_back_to_the_joints_seen() -> None:
    J = np.full((1, 17, 3), np.nan)
    J[0, 0] = [1.0, 2.0, 1.7]
    J[0, 5] = [3.0, 2.0, 1.4]
    np.testing.assert_allclose(floor_position(J), [[2.0, 2.0]])


def test_load_people3d_round_trip(tmp_path: Path) -> None:
    out = tmp_path / "poses.jsonl"
    with PosesWriter(out, fps=25.0) as w:
        w.write(people(0))
        w.write(People3D.empty(1, 2))
    back = load_people3d(out, num_cameras=2)
    assert [len(p) for p in back] == [2, 0]
    np.testing.assert_allclose(back[0].joints, people(0).joints, atol=1e-4)
    assert back[0].ids.tolist() == [4, 7] and back[0].detections.shape == (2, 2)
