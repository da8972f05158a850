"""File sinks: each writes its file from the frames it is given, and closes once."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from stereopose.io.exports import read_trc
from stereopose.io.results import read_poses
from stereopose.io.sinks import CsvSink, FrameResult, PosesSink, TracksSink, TrcSink, TwoWaySink
from stereopose.tracking.positioning import Trajectory
from stereopose.types import People3D


def frame(f: int, ids: list[int], shift: float = 0.0) -> FrameResult:
    P = len(ids)
    J = np.arange(P * 17 * 3, dtype=float).reshape(P, 17, 3) / 100 + f / 10 + shift
    people = People3D(
        f,
        J,
        np.full((P, 17), 0.8),
        np.array(ids, dtype=np.int64),
        np.zeros((P, 17)),
        np.full((P, 17), 2),
        np.full((P, 2), -1),
    )
    return FrameResult(f, f / 25, {}, people)


def test_file_sinks_write_every_frame(tmp_path: Path) -> None:
    track = Trajectory(1, 0, 0.0, 2, 0.08, 3)
    sinks = [
        PosesSink(tmp_path / "p.jsonl", 25.0),
        CsvSink(tmp_path / "j.csv", 25.0),
        TrcSink(tmp_path / "trc", 25.0),
        TracksSink(tmp_path / "t.json", lambda: [track]),
    ]
    for f, ids in enumerate([[1], [1, 2], [], [1]]):
        for sink in sinks:
            sink.write(frame(f, ids))
    paths = [p for s in sinks for p in s.close()]
    assert [p.name for p in paths] == ["p.jsonl", "j.csv", "person_1.trc", "person_2.trc", "t.json"]
    assert [s.close() for s in sinks] == [[], [], [], []]
    assert [f for f, _, _ in read_poses(tmp_path / "p.jsonl")] == [0, 1, 2, 3]
    assert len((tmp_path / "j.csv").read_text().splitlines()) == 1 + 4 * 17
    assert read_trc(tmp_path / "trc" / "person_1.trc")[0].tolist() == [0, 1, 2, 3]
    assert json.loads((tmp_path / "t.json").read_text())[0]["id"] == 1


def test_two_way_hands_the_smoothed_frames_to_its_sinks_at_close(tmp_path: Path) -> None:
    def smooth(people: list[People3D]) -> list[People3D]:
        return [
            People3D(
                p.frame, p.joints + 1.0, p.conf, p.ids, p.reprojection_px, p.views, p.detections
            )
            for p in people
        ]

    sink = TwoWaySink([TrcSink(tmp_path / "trc", 25.0)], smooth)
    for f in range(3):
        sink.write(frame(f, [5]))
    # nothing before the end: the folder is made (and tried) at once, but stays empty
    assert sink.frames_kept == 3 and not any((tmp_path / "trc").iterdir())
    assert [p.name for p in sink.close()] == ["person_5.trc"] and sink.frames_kept == 0
    _, _, J, _, _ = read_trc(tmp_path / "trc" / "person_5.trc")
    np.testing.assert_allclose(
        J, np.stack([frame(f, [5], 1.0).people3d.joints[0] for f in range(3)]), atol=1e-5
    )


def test_two_way_writes_the_online_frames_if_smoothing_fails(tmp_path: Path, caplog) -> None:
    def fail(people):
        raise ValueError("no track")

    sink = TwoWaySink([CsvSink(tmp_path / "j.csv", 25.0)], fail)
    for f in range(3):
        sink.write(frame(f, [5]))
    assert sink.close() == [tmp_path / "j.csv"]
    assert "two-way smoothing failed" in caplog.text
    assert len((tmp_path / "j.csv").read_text().splitlines()) == 1 + 3 * 17
