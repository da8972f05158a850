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
