"""TRC and CSV exports."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from stereopose.errors import StereoposeError
from stereopose.io.exports import CsvExporter, TrcExporter, read_trc, write_trc
from stereopose.skeleton import JOINTS
from stereopose.types import People3D


def people(frame: int, ids: list[int], rng: np.random.Generator) -> People3D:
    P = len(ids)
    J = rng.uniform(0, 3, (P, 17, 3))
    J[:, 3] = np.nan
    return People3D(
        frame,
        J,
        np.where(np.isfinite(J[..., 0]), 0.8, 0.0),
        np.array(ids),
        np.zeros((P, 17)),
        np.full((P, 17), 2),
        np.full((P, 4), -1),
    )


def test_trc_round_trip_and_y_up_axes(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    J = rng.uniform(-2, 2, (5, 17, 3))
    J[2, 4] = np.nan
    write_trc(tmp_path / "a.trc", np.arange(10, 15), J, 30.0)
    frames, times, back, names, rate = read_trc(tmp_path / "a.trc")
    np.testing.assert_array_equal(frames, np.arange(10, 15))
    np.testing.assert_allclose(times, np.arange(10, 15) / 30.0, atol=1e-6)
    np.testing.assert_allclose(back, J, atol=1e-5)
    assert names == list(JOINTS) and rate == 30.0
    lines = (tmp_path / "a.trc").read_text().splitlines()
    assert lines[0].startswith("PathFileType\t4\t(X/Y/Z)\ta.trc")
    assert lines[2].split("\t")[:5] == ["30", "30", "5", "17", "m"]
    # TRC's Y (up) is the world's z
    row = lines[5].split("\t")
    assert float(row[3]) == pytest.approx(J[0, 0, 2], abs=1e-5)


def test_trc_exporter_fills_gaps_with_empty_cells(tmp_path: Path) -> None:
    rng = np.random.default_rng(1)
    exp = TrcExporter(tmp_path / "trc", 25.0)
    for f in (0, 1, 4):
        exp.add(people(f, [1, 2] if f < 4 else [2], rng))
    paths = exp.close()
    assert [p.name for p in paths] == ["person_1.trc", "person_2.trc"]
    frames, _, J, _, _ = read_trc(paths[1])
    np.testing.assert_array_equal(frames, [0, 1, 2, 3, 4])
    assert np.isnan(J[2:4]).all() and np.isfinite(J[4, 0]).all()
    assert read_trc(paths[0])[0].tolist() == [0, 1]


def test_unreadable_trc_names_the_file(tmp_path: Path) -> None:
    bad = tmp_path / "bad.trc"
    bad.write_text("not a trc\n")
    with pytest.raises(StereoposeError, match=r"bad\.trc.*not a readable TRC"):
        read_trc(bad)


def test_csv_rows(tmp_path: Path) -> None:
    rng = np.random.default_rng(2)
    exp = CsvExporter(tmp_path / "j.csv", 25.0)
    exp.add(people(50, [3], rng))
    exp.add(people(51, [], rng))
    exp.close()
    rows = (tmp_path / "j.csv").read_text().splitlines()
    assert rows[0] == "frame,t,id,joint,x,y,z,conf"
    assert len(rows) == 1 + 16  # the missing joint has no row
    frame, t, i, joint, *_ = rows[1].split(",")
    assert (frame, float(t), i, joint) == ("50", 2.0, "3", "nose")


def test_unwritable_csv_is_a_clear_error(tmp_path: Path) -> None:
    (tmp_path / "file").write_text("")
    with pytest.raises(StereoposeError, match="cannot write CSV"):
        CsvExporter(tmp_path / "file" / "j.csv", 25.0)


def _scene(rng: np.random.Generator, frames: int = 40) -> list[People3D]:
    """People 1-3 coming and going (gaps of a few frames), some frames with nobody."""
    out = []
    for f in range(frames):
        ids = [i for i in (1, 2, 3) if rng.random() < (0.9, 0.5, 0.3)[i - 1] and f >= 2 * i]
        out.append(people(f, ids, rng))
    return out


def _old_trc(tmp: Path, frames: list[People3D], fps: float) -> dict[int, Path]:
    """The all-at-end writer: each person's joints collected, then write_trc."""
    got: dict[int, dict[int, np.ndarray]] = {}
    for p in frames:
        for k, i in enumerate(p.ids):
            got.setdefault(int(i), {})[p.frame] = p.joints[k]
    paths = {}
    for i, rows in got.items():
        fr = np.arange(min(rows), max(rows) + 1)
        J = np.full((fr.size, 17, 3), np.nan)
        for f, joints in rows.items():
            J[f - fr[0]] = joints
        paths[i] = tmp / f"person_{i}.trc"
        write_trc(paths[i], fr, J, fps)
    return paths


def _same_trc(streamed: Path, old: Path) -> None:
    a, b = streamed.read_text().splitlines(), old.read_text().splitlines()
    assert a[:2] == b[:2] and a[3:] == b[3:]  # the rows byte for byte, gaps included
    ha, hb = a[2].split("\t"), b[2].split("\t")
    assert [int(float(x)) if x != "m" else x for x in ha] == [
        int(float(x)) if x != "m" else x for x in hb
    ]  # the header's numbers; NumFrames and the last frame zero-padded
    for x, y in zip(read_trc(streamed), read_trc(old), strict=True):
        np.testing.assert_array_equal(x, y)


@pytest.mark.parametrize("idle", [None, 3])
def test_trc_streaming_matches_the_all_at_end_writer(tmp_path: Path, idle) -> None:
    frames = _scene(np.random.default_rng(7))
    old = _old_trc(tmp_path / "old", frames, 30.0)
    exp = TrcExporter(tmp_path / "new", 30.0, idle_frames=idle)
    for p in frames:
        exp.add(p)
        assert len(exp._open) <= 3
    paths = exp.close()
    assert [p.name for p in paths] == [f"person_{i}.trc" for i in sorted(old)]
    for p in paths:
        _same_trc(p, old[int(p.stem.split("_")[1])])
    assert exp.close() == paths and not exp._open


def test_trc_is_readable_while_it_is_written(tmp_path: Path) -> None:
    rng = np.random.default_rng(3)
    exp = TrcExporter(tmp_path, 25.0)
    for f in (5, 6, 9):
        exp.add(people(f, [4], rng))
        frames, _, J, _, _ = read_trc(tmp_path / "person_4.trc")
        assert frames[0] == 5 and frames[-1] == f and len(J) == f - 4
        header = (tmp_path / "person_4.trc").read_text().splitlines()[2].split("\t")
        assert int(header[2]) == f - 4 and int(header[7]) == f  # NumFrames kept up to date
    exp.close()


def test_trc_exporter_holds_nothing_per_frame(tmp_path: Path) -> None:
    rng = np.random.default_rng(5)
    exp = TrcExporter(tmp_path, 25.0, idle_frames=10)
    one = people(0, [1, 2], rng)
    for f in range(2000):  # person 1 always there; person 2 leaves at 100; 3 comes at 1500
        ids = [1] + ([2] if f < 100 else []) + ([3] if f >= 1500 else [])
        exp.add(
            People3D(
                f,
                one.joints[: len(ids)],
                one.conf[: len(ids)],
                np.array(ids),
                one.reprojection_px[: len(ids)],
                one.views[: len(ids)],
                one.detections[: len(ids)],
            )
        )
        if f == 200:
            assert sorted(exp._open) == [1]  # person 2's file closed once idle
    assert sorted(exp._open) == [1, 3]
    exp.close()
    assert read_trc(tmp_path / "person_2.trc")[0].tolist() == list(range(100))
    assert read_trc(tmp_path / "person_1.trc")[0].size == 2000


def test_trc_file_closed_when_idle_is_reopened_on_return(tmp_path: Path) -> None:
    rng = np.random.default_rng(8)
    frames = [people(f, [1] if f in (0, 1, 10) else [], rng) for f in range(12)]
    exp = TrcExporter(tmp_path / "new", 25.0, idle_frames=2)
    for p in frames[:5]:
        exp.add(p)
    assert not exp._open  # closed after 2 frames unseen
    for p in frames[5:]:
        exp.add(p)
    assert list(exp._open) == [1]  # reopened at frame 10
    exp.close()
    _same_trc(tmp_path / "new" / "person_1.trc", _old_trc(tmp_path, frames, 25.0)[1])
