"""3D poses segments: split by wall time, never overwritten, readable after a crash at any byte,
a failing disk survived."""

from __future__ import annotations

import gzip
import json
import os
import signal
import subprocess
import sys
from datetime import UTC, datetime
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from stereopose.errors import ConfigError, OutputError, StereoposeError
from stereopose.io.results import read_poses
from stereopose.io.sinks import FrameResult, PosesSink
from stereopose.io.sinks.segments import SegmentSettings, SegmentSink, segment_stem
from stereopose.types import People3D

# 2024-05-01 12:59:55 UTC: the first hour's segment starts 5 s before the hour
WALL = datetime(2024, 5, 1, 12, 59, 55, tzinfo=UTC).timestamp()


def frame(f: int, fps: float = 5.0, ids: tuple[int, ...] = (1, 2)) -> FrameResult:
    P = len(ids)
    J = np.arange(P * 17 * 3, dtype=float).reshape(P, 17, 3) / 100 + f / 10
    people = People3D(
        f,
        J,
        np.full((P, 17), 0.8),
        np.array(ids, dtype=np.int64),
        np.zeros((P, 17)),
        np.full((P, 17), 2),
        np.full((P, 2), -1),
    )
    return FrameResult(f, f / fps, {}, people)


def write_segments(out: Path, frames: int, wall: float = WALL, **kw: float) -> SegmentSink:
    sink = SegmentSink(out, 5.0, wall_start=wall, settings=SegmentSettings(**kw))
    for f in range(frames):
        sink.write(frame(f))
    return sink


def test_segments_start_on_whole_multiples_of_wall_time(tmp_path: Path) -> None:
    sink = write_segments(tmp_path, 5 * 25, segment_s=10.0)  # 25 s from 12:59:55
    paths = sink.close()
    assert [p.name for p in paths] == [
        "20240501-125955.jsonl.gz",  # the first frame's time, up to the next multiple
        "20240501-130000.jsonl.gz",
        "20240501-130010.jsonl.gz",
    ]
    per_file = [[f for f, _, _ in read_poses(p)] for p in paths]
    assert per_file == [list(range(25)), list(range(25, 75)), list(range(75, 125))]
    assert [f for f, _, _ in read_poses(tmp_path / "poses")] == list(range(125))
    assert sink.frames == 125 and sink.frames_lost == 0 and sink.incomplete is None
    assert sink.close() == []


def test_segment_lines_are_the_poses_lines_with_their_wall_time(tmp_path: Path) -> None:
    """Each line is the poses3d.jsonl line, its keys in order, with `wall_t` after `t`."""
    plain = PosesSink(tmp_path / "poses3d.jsonl", 5.0)
    segments = SegmentSink(tmp_path, 5.0, wall_start=WALL)
    for f in range(12):
        plain.write(frame(f))
        segments.write(frame(f))
    plain.close()
    (path,) = segments.close()
    lines = gzip.decompress(path.read_bytes()).decode().splitlines()
    expected = (tmp_path / "poses3d.jsonl").read_text().splitlines()
    assert len(lines) == len(expected) == 12
    for line, want in zip(lines, expected, strict=True):
        rec = json.loads(line)
        assert rec.pop("wall_t") == round(WALL + rec["t"], 3)
        assert list(rec) == list(json.loads(want)) and rec == json.loads(want)
        assert line.startswith(f'{{"frame":{rec["frame"]},"t":')


def test_flushed_frames_are_on_disk_before_close(tmp_path: Path) -> None:
    sink = SegmentSink(
        tmp_path, 5.0, wall_start=WALL, settings=SegmentSettings(segment_flush_s=1.0)
    )
    for f in range(7):  # 1.2 s of frames: the first 5 (t < 1 s) are flushed at t = 1 s
        sink.write(frame(f))
    assert sink.frames == 6 and [f for f, _, _ in read_poses(sink.path)] == list(range(6))
    sink.close()
    assert [f for f, _, _ in read_poses(sink.path)] == list(range(7))


def test_a_taken_name_is_never_overwritten(tmp_path: Path) -> None:
    folder = tmp_path / "poses"
    folder.mkdir()
    taken = folder / f"{segment_stem(WALL)}.jsonl.gz"
    taken.write_bytes(b"someone else's")
    (path,) = write_segments(tmp_path, 3).close()
    assert path.name == f"{segment_stem(WALL)}_001.jsonl.gz"
    assert taken.read_bytes() == b"someone else's"
    assert [f for f, _, _ in read_poses(path)] == [0, 1, 2]


def test_settings_and_arguments_are_checked() -> None:
    with pytest.raises(ConfigError, match=r"storage\.segment_s: expected .* got 0"):
        SegmentSettings(segment_s=0)
    with pytest.raises(ConfigError, match=r"storage\.segment_flush_s: .* got nan"):
        SegmentSettings(segment_flush_s=float("nan"))
    with pytest.raises(StereoposeError, match="wall_start"):
        SegmentSink("/tmp", 5.0, wall_start=float("inf"))


def test_an_unwritable_folder_is_refused_at_once(tmp_path: Path) -> None:
    (tmp_path / "poses").write_text("a file where the folder should be")
    with pytest.raises(OutputError, match="poses: cannot write 3D poses segments"):
        SegmentSink(tmp_path, 5.0, wall_start=WALL)


def test_an_empty_folder_is_an_error_not_nothing(tmp_path: Path) -> None:
    with pytest.raises(StereoposeError, match="no 3D poses segments"):
        list(read_poses(tmp_path))


@pytest.fixture(scope="module")
def whole_segment(tmp_path_factory) -> bytes:
    """A segment of 40 frames in several members (about one per second of frames)."""
    out = tmp_path_factory.mktemp("whole")
    (path,) = write_segments(out, 40, WALL + 5, segment_flush_s=1.0).close()
    return path.read_bytes()


@settings(
    max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(cut=st.integers(min_value=0, max_value=10**6))
def test_a_segment_cut_at_any_byte_reads_to_its_last_complete_line(
    tmp_path: Path, whole_segment: bytes, cut: int
) -> None:
    path = tmp_path / "cut.jsonl.gz"
    path.write_bytes(whole_segment[: cut % (len(whole_segment) + 1)])
    frames = [f for f, _, _ in read_poses(path)]  # never an error: a crash is not damage
    assert frames == list(range(len(frames)))
    if cut % (len(whole_segment) + 1) == len(whole_segment):
        assert len(frames) == 40


@settings(
    max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(data=st.binary(max_size=400), at=st.integers(min_value=0, max_value=10**6))
def test_any_bytes_in_a_segment_give_frames_or_an_error_naming_it(
    tmp_path: Path, whole_segment: bytes, data: bytes, at: int
) -> None:
    at %= len(whole_segment) + 1
    path = tmp_path / "hostile.jsonl.gz"
    path.write_bytes(whole_segment[:at] + data + whole_segment[at:])
    skipped: list[tuple[int, str]] = []
    try:
        frames = [f for f, _, _ in read_poses(path)]
    except StereoposeError as e:
        assert "hostile.jsonl.gz" in str(e)
    else:
        assert all(isinstance(f, int) for f in frames)
    assert all(isinstance(f, int) for f, _, _ in read_poses(path, skipped=skipped))


def test_damaged_gzip_data_is_skipped_when_asked(tmp_path: Path, whole_segment: bytes) -> None:
    path = tmp_path / "damaged.jsonl.gz"
    second = whole_segment.index(b"\x1f\x8b\x08", 1)  # where the second member starts
    first = len(gzip.decompress(whole_segment[:second]).splitlines())
    path.write_bytes(whole_segment[:second] + b"not gzip at all" + whole_segment[second:])
    with pytest.raises(StereoposeError, match=rf"damaged\.jsonl\.gz:{first + 1}: damaged gzip"):
        list(read_poses(path))
    skipped: list[tuple[int, str]] = []
    assert [f for f, _, _ in read_poses(path, skipped=skipped)] == list(range(first))
    assert skipped[0][0] == first + 1 and "damaged gzip" in skipped[0][1]


KILLED = """
import sys
import numpy as np
from stereopose.io.sinks import FrameResult
from stereopose.io.sinks.segments import SegmentSettings, SegmentSink
from stereopose.types import People3D
sink = SegmentSink(sys.argv[1], 25.0, wall_start=1714568400.0,
                   settings=SegmentSettings(segment_flush_s=0.2))
J = np.random.default_rng(0).normal(size=(3, 17, 3))
f, on_disk = 0, 0
while True:
    people = People3D(f, J, np.ones((3, 17)), np.arange(3), np.zeros((3, 17)),
                      np.full((3, 17), 2), np.full((3, 2), -1))
    sink.write(FrameResult(f, f / 25, {}, people))
    f += 1
    if sink.frames != on_disk:
        on_disk = sink.frames
        print(on_disk, flush=True)
"""


@pytest.mark.slow
def test_a_writer_killed_at_any_moment_leaves_a_readable_segment(tmp_path: Path) -> None:
    proc = subprocess.Popen(
        [sys.executable, "-c", KILLED, str(tmp_path)], stdout=subprocess.PIPE, text=True
    )
    reported = 0
    try:
        for line in proc.stdout:
            reported = int(line)
            if reported >= 500:
                break
    finally:
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
    assert proc.returncode == -signal.SIGKILL and reported >= 500
    (path,) = (tmp_path / "poses").iterdir()
    frames = [f for f, _, _ in read_poses(path)]
    assert frames == list(range(len(frames))) and len(frames) >= reported


FULL_DISK = """
import json, resource, signal, sys
import numpy as np
from stereopose.io.sinks import FrameResult
from stereopose.io.sinks.segments import SegmentSink
from stereopose.types import People3D
signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # a write past the limit fails with EFBIG
sink = SegmentSink(sys.argv[1], 1.0, wall_start=1714568400.0)
J = np.random.default_rng(0).normal(size=(2, 17, 3))
sent = 0
def write():
    global sent
    people = People3D(sent, J + sent, np.ones((2, 17)), np.arange(2), np.zeros((2, 17)),
                      np.full((2, 17), 2), np.full((2, 2), -1))
    sink.write(FrameResult(sent, float(sent), {}, people))
    sink.flush()
    sent += 1
soft, hard = resource.getrlimit(resource.RLIMIT_FSIZE)
resource.setrlimit(resource.RLIMIT_FSIZE, (6000, hard))  # the disk fills up
while not sink.frames_lost:
    write()
resource.setrlimit(resource.RLIMIT_FSIZE, (sink.path.stat().st_size, hard))  # nothing fits
write(), write()
resource.setrlimit(resource.RLIMIT_FSIZE, (soft, hard))  # space again
for _ in range(4):
    write()
paths = sink.close()
print(json.dumps({"paths": [str(p) for p in paths], "frames": sink.frames, "sent": sent,
                  "lost": sink.frames_lost, "incomplete": sink.incomplete}))
"""


@pytest.mark.slow
def test_a_full_disk_loses_frames_counted_and_writing_comes_back(tmp_path: Path) -> None:
    done = subprocess.run(
        [sys.executable, "-c", FULL_DISK, str(tmp_path)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert done.returncode == 0, done.stderr
    result = json.loads(done.stdout)
    sent, kept = result["sent"], result["frames"]
    assert result["lost"] == 3 and kept == sent - 3
    assert result["incomplete"].startswith("3 frame(s) of 3D poses lost (File too large)")
    assert done.stderr.count("cannot write 3D poses") == 1  # once for the spell
    assert "3D poses written again" in done.stderr
    (path,) = result["paths"]
    # the file was cut back to its last whole member: the frames before and after, in order
    before = kept - 4
    assert [f for f, _, _ in read_poses(path)] == [*range(before), *range(sent - 4, sent)]
