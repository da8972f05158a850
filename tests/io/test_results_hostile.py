"""Hostile 3D poses files: a StereoposeError naming the line, or the line skipped and counted."""

from __future__ import annotations

import json
import math
import os
import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from stereopose.errors import StereoposeError
from stereopose.io.results import PosesWriter, load_people3d, read_poses
from stereopose.types import People3D

FUZZ = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])

json_values = st.recursive(
    st.none()
    | st.booleans()
    | st.integers(min_value=-(10**40), max_value=10**40)
    | st.floats(allow_nan=True, allow_infinity=True)
    | st.text(max_size=4),
    lambda inner: st.lists(inner, max_size=5) | st.dictionaries(st.text(max_size=4), inner),
    max_leaves=25,
)


def good_line(frame: int) -> bytes:
    J = np.arange(17 * 3, dtype=float).reshape(1, 17, 3) / 10
    z = np.zeros((1, 17))
    people = People3D(frame, J, z + 1, np.array([1]), z, z.astype(int) + 2, np.zeros((1, 2), int))
    with tempfile.TemporaryDirectory() as d:
        with PosesWriter(Path(d) / "p.jsonl", fps=25.0) as w:
            w.write(people)
        return (Path(d) / "p.jsonl").read_bytes()


def check_file(body: bytes) -> None:
    """Strictly: frames or a StereoposeError naming the file; leniently: the good lines around
    the hostile one always come back, and whatever did is usable."""
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "poses.jsonl"
        path.write_bytes(body)
        try:
            list(read_poses(path))
        except StereoposeError as e:
            assert str(e).startswith(f"{path}:")
        try:
            load_people3d(path, 2)
        except StereoposeError as e:
            assert str(e).startswith(f"{path}:")
        path.write_bytes(good_line(0) + body.replace(b"\n", b" ") + b"\n" + good_line(2))
        skipped: list[tuple[int, str]] = []
        frames = list(read_poses(path, skipped=skipped))
        assert frames[0][0] == 0 and frames[-1][0] == 2 and len(frames) + len(skipped) <= 3
        for frame, t, people in frames:
            assert 0 <= frame < 2**63 and (t is None or math.isfinite(t))
            for p in people:
                assert p["joints_array"].shape == (17, 3)
                assert -(2**63) < int(p["id"]) < 2**63
                pos = p.get("position")
                assert pos is None or np.isfinite(np.array(pos, float)).all()


@FUZZ
@given(st.binary(max_size=200))
def test_arbitrary_bytes(raw: bytes) -> None:
    check_file(raw)


@FUZZ
@given(json_values)
def test_arbitrary_json(doc: object) -> None:
    check_file(json.dumps(doc).encode())
    check_file(json.dumps({"frame": 1, "people": doc}).encode())
    check_file(json.dumps({"frame": doc, "t": doc, "people": []}).encode())


@FUZZ
@given(
    st.dictionaries(
        st.sampled_from(["id", "joints", "position", "velocity", "conf", "views", "predicted"]),
        json_values,
    )
)
def test_arbitrary_people(person: dict) -> None:
    base = {"id": 1, "joints": [[0.0, 0.0, 1.0]] * 17}
    check_file(json.dumps({"frame": 1, "people": [{**base, **person}]}).encode())


@pytest.mark.parametrize(
    ("line", "problem"),
    [
        (b"[" * 100_000 + b"]" * 100_000, "nested too deeply"),
        (b'{"frame": 1e999, "people": []}', "OverflowError"),
        (b'{"frame": 99999999999999999999999, "people": []}', "not a frame number"),
        (b'{"frame": 1, "t": NaN, "people": []}', "not a time"),
        (b'{"frame": 1, "people": ""}', "must be a list"),
        (b'{"frame": 1, "people": [{"id": 1e999, "joints": []}]}', None),
        (b'{"frame": 1, "people": [{"id": 1, "joints": [[1e999, 0, 0]]}]}', None),
        (b'{"frame": 1, "people": [{"id": 1, "joints": [[' + b"9" * 400 + b", 0, 0]]}]}", None),
        (b"\xff\xfe not text", "not UTF-8"),
    ],
)
def test_damaged_lines(tmp_path: Path, line: bytes, problem: str | None) -> None:
    path = tmp_path / "poses.jsonl"
    path.write_bytes(good_line(0) + line + b"\n" + good_line(2))
    with pytest.raises(StereoposeError, match=rf"poses\.jsonl:2: malformed.*{problem or ''}"):
        list(read_poses(path))
    skipped: list[tuple[int, str]] = []
    assert [f for f, _, _ in read_poses(path, skipped=skipped)] == [0, 2]
    assert [n for n, _ in skipped] == [2]


def test_overlong_line_is_skipped_without_reading_it_whole(tmp_path: Path, monkeypatch) -> None:
    from stereopose.io import results

    monkeypatch.setattr(results, "MAX_LINE_BYTES", 1000)
    path = tmp_path / "poses.jsonl"
    path.write_bytes(good_line(0) + b"[" * 5000 + b"\n" + good_line(2))
    skipped: list[tuple[int, str]] = []
    assert [f for f, _, _ in read_poses(path, skipped=skipped)] == [0, 2]
    assert skipped and "longer than" in skipped[0][1]


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="named pipes need POSIX")
def test_a_named_pipe_is_refused_not_waited_on(tmp_path: Path) -> None:
    fifo = tmp_path / "poses.jsonl"
    os.mkfifo(fifo)
    with pytest.raises(StereoposeError, match="not a regular file"):
        list(read_poses(fifo))
