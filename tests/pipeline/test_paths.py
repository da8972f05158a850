"""Outputs never written over inputs or each other, and folders that hold one run."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from stereopose.errors import ConfigError
from stereopose.pipeline.paths import (
    POSE_READS,
    RUN_PATTERNS,
    TRC_PATTERNS,
    Place,
    check_places,
    pattern_products,
    previous_outputs,
    remove_outputs,
    run_products,
    same_path,
)


@pytest.fixture(scope="module")
def tree(tmp_path_factory) -> Path:
    """base/calib.toml, base/pose/cam01_json/f_0.json, base/a/b/, base/link -> a,
    base/calib_link.toml -> calib.toml, base/hard.toml (a hard link to calib.toml)."""
    base = tmp_path_factory.mktemp("tree")
    (base / "calib.toml").write_text("[cam01]\n")
    (base / "pose" / "cam01_json").mkdir(parents=True)
    (base / "pose" / "cam01_json" / "f_0.json").write_text('{"people": []}')
    (base / "a" / "b").mkdir(parents=True)
    (base / "link").symlink_to(base / "a", target_is_directory=True)
    (base / "calib_link.toml").symlink_to(base / "calib.toml")
    os.link(base / "calib.toml", base / "hard.toml")
    return base


def _inputs(base: Path) -> list[Place]:
    return [Place("--calib", base / "calib.toml"), Place("--pose", base / "pose", POSE_READS)]


def _refused(base: Path, *outputs: Path) -> str:
    with pytest.raises(ConfigError) as e:
        check_places(_inputs(base), [Place(f"out{i}", p) for i, p in enumerate(outputs)])
    return str(e.value)


def test_an_output_that_is_an_input_is_refused_however_it_is_spelled(tree: Path) -> None:
    for spelling in (
        tree / "calib.toml",
        tree / "a" / ".." / "calib.toml",
        tree / "link" / "b" / ".." / ".." / "calib.toml",
        tree / "calib_link.toml",  # a symbolic link to it
        tree / "hard.toml",  # a hard link to it
    ):
        message = _refused(tree, spelling)
        assert str(spelling) in message and str(tree / "calib.toml") in message, spelling
        assert "--calib" in message


def test_an_output_inside_an_input_folder_where_it_is_read_is_refused(tree: Path) -> None:
    for inside in (
        tree / "pose" / "cam01_json" / "f_1.json",
        tree / "pose" / "new_1.JSON",
        tree / "pose" / "cam02_json" / "x.csv",
        tree / "pose",
    ):
        message = _refused(tree, inside)
        assert f"inside the --pose folder {tree / 'pose'}, which is read as input" in message or (
            f"it is the --pose {tree / 'pose'}" in message
        )
    with pytest.raises(ConfigError, match="inside the --pose folder"):  # a new camera folder
        check_places(_inputs(tree), [Place("--trc", tree / "pose" / "cam09", folder=True)])
    # a file the keypoints reader never reads, beside the camera folders
    check_places(_inputs(tree), [Place("--out", tree / "pose" / "poses3d.jsonl")])


def test_every_output_inside_an_image_folder_is_refused(tree: Path) -> None:
    photos = [Place("--images", tree / "a")]  # reads everything in it, sub-folders as cameras
    for inside in (tree / "a" / "notes.txt", tree / "link" / "b" / "report.png"):
        with pytest.raises(ConfigError, match=f"inside the --images folder {tree / 'a'}"):
            check_places(photos, [Place("--report", inside)])


def test_a_hard_link_to_a_file_inside_an_input_folder_is_refused(tmp_path: Path) -> None:
    (tmp_path / "pose" / "cam01_json").mkdir(parents=True)
    frame = tmp_path / "pose" / "cam01_json" / "f_0.json"
    frame.write_text("{}")
    os.link(frame, tmp_path / "elsewhere.json")
    with pytest.raises(ConfigError, match="hard link to the --pose file"):
        check_places(
            [Place("--pose", tmp_path / "pose")], [Place("--out", tmp_path / "elsewhere.json")]
        )


def test_two_outputs_at_one_path_are_refused(tree: Path) -> None:
    message = _refused(tree, tree / "p.jsonl", tree / "a" / ".." / "p.jsonl")
    assert "out0 writes the same path" in message and "give each output its own path" in message
    _refused(tree, tree / "link" / "x.csv", tree / "a" / "x.csv")  # one through a link


def test_a_file_inside_an_output_folder_is_refused(tree: Path) -> None:
    trc = Place("--trc", tree / "trc", folder=True)
    for outputs in (
        [trc, Place("--csv", tree / "trc" / "person_1.trc")],
        [Place("--csv", tree / "trc" / "joints.csv"), trc],
    ):
        with pytest.raises(ConfigError, match=f"inside the --trc folder {tree / 'trc'}"):
            check_places(_inputs(tree), outputs)


def test_distinct_outputs_beside_the_inputs_are_fine(tree: Path) -> None:
    outputs = [tree / "p.jsonl", tree / "a" / "p.jsonl", tree / "calib.toml.bak", tree / "pose2"]
    check_places(_inputs(tree), [Place(str(p), p) for p in outputs])


_WAYS = st.sampled_from([".", "a/..", "a/b/../..", "link/..", "link/b/../.."])


@settings(max_examples=60, deadline=None)
@given(ways=st.lists(_WAYS, max_size=4), through_link=st.booleans())
def test_any_spelling_of_an_input_is_refused(tree: Path, ways: list[str], through_link) -> None:
    prefix = tree.joinpath(*ways)
    target = prefix / ("calib_link.toml" if through_link else "calib.toml")
    with pytest.raises(ConfigError):
        check_places(_inputs(tree), [Place("--out", target)])
    assert same_path(target, tree / "calib.toml")


@settings(max_examples=60, deadline=None)
@given(
    ways=st.lists(_WAYS, max_size=3),
    name=st.text("abcxyz_.-0123456789", min_size=1, max_size=12).filter(
        lambda n: n not in (".", "..") and n not in ("calib.toml", "calib_link.toml", "hard.toml")
    ),
)
def test_a_new_name_beside_the_inputs_is_never_refused(tree: Path, ways: list[str], name) -> None:
    check_places(_inputs(tree), [Place("--out", tree.joinpath(*ways) / name)])


def _touch(*paths: Path) -> None:
    for p in paths:
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(p.name)


def test_a_folder_with_a_previous_run_is_refused_and_replaced_only_with_overwrite(
    tmp_path: Path,
) -> None:
    run = tmp_path / "out"
    ours = [
        run / "poses3d.jsonl",
        run / "summary.json",
        run / "events.sqlite-wal",
        run / "trc" / "person_3.trc",
        run / "overlays" / "cam01.mp4",
    ]
    mine = [run / "notes.txt", run / "trc" / "readme.md", run / "overlays" / "cam01.png"]
    _touch(*ours, *mine)
    before = {p: (p.read_bytes(), p.stat().st_mtime_ns) for p in mine}
    folder = Place("output", run)
    with pytest.raises(ConfigError, match="already holds a previous run's outputs") as e:
        previous_outputs(folder, run_products, overwrite=False)
    assert str(run) in str(e.value) and "--overwrite" in str(e.value)
    assert all(p.exists() for p in ours)  # refused: nothing removed
    previous = previous_outputs(folder, run_products, overwrite=True)
    assert sorted(previous) == sorted(ours)
    remove_outputs(previous)
    assert not any(p.exists() for p in ours)
    assert {p: (p.read_bytes(), p.stat().st_mtime_ns) for p in mine} == before


def test_the_outputs_a_summary_lists_are_a_previous_run_s(tmp_path: Path) -> None:
    run = tmp_path / "out"
    _touch(run / "extra" / "made_by_the_run.bin", run / "other.bin")
    listed = [str(run / "extra" / "made_by_the_run.bin"), str(tmp_path / "x")]
    (run / "summary.json").write_text(json.dumps({"outputs": listed}))
    found = run_products(run)
    assert run / "extra" / "made_by_the_run.bin" in found and run / "summary.json" in found
    assert run / "other.bin" not in found and tmp_path / "x" not in found


def test_an_input_in_the_folder_is_never_a_previous_output(tmp_path: Path) -> None:
    run = tmp_path / "out"
    _touch(run / "calib.toml")
    calib = Place("calibration", run / "calib.toml")
    assert previous_outputs(Place("output", run), run_products, False, [calib]) == []


def test_patterns_match_only_the_product_s_files(tmp_path: Path) -> None:
    _touch(tmp_path / "person_1.trc", tmp_path / "person.trc", tmp_path / "sub" / "person_2.trc")
    assert pattern_products(TRC_PATTERNS)(tmp_path) == [tmp_path / "person_1.trc"]
    assert pattern_products(RUN_PATTERNS)(tmp_path) == []
    assert previous_outputs(Place("--trc", tmp_path / "missing"), run_products, False) == []
