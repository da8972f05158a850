"""`stereopose run` and its folder: never the user's files written over, one run per folder.

Two cameras of two blank 64x48 frames each (image folders): the run is quick and writes every
output of a run folder, with nobody in it.
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from stereopose.cli import main

CALIB = "# our rig: keep this comment\n" + "".join(
    f"""[{cam}]
name = "{cam}"
size = [ 64.0, 48.0]
matrix = [ [ 50.0, 0.0, 32.0], [ 0.0, 50.0, 24.0], [ 0.0, 0.0, 1.0]]
distortions = [ 0.0, 0.0, 0.0, 0.0]
rotation = [ 0.0, {ry}, 0.0]
translation = [ {tx}, 0.0, 5.0]
fisheye = false
"""
    for cam, ry, tx in (("cam01", 0.0, 0.0), ("cam02", 0.5, 1.0), ("cam03", -0.5, -1.0))
)
SITE = """fps = 25.0  # our site
[[zones]]
name = "bay"
kind = "work_area"
polygon = [[0.0, 0.0], [3.0, 0.0], [3.0, 3.0], [0.0, 3.0]]
z = [0.0, 2.5]
"""


def _config(folder: Path, output: str, extra: str = "") -> Path:
    """folder/calib.toml, site.toml, cam01/ and cam02/ (two frames each), and the run's
    config.toml writing to `output`."""
    (folder / "calib.toml").write_text(CALIB)
    (folder / "site.toml").write_text(SITE)
    for cam in ("cam01", "cam02"):
        (folder / cam).mkdir(exist_ok=True)
        for i in range(2):
            cv2.imwrite(str(folder / cam / f"{i:04d}.png"), np.zeros((48, 64, 3), np.uint8))
    cameras = "".join(f'[[cameras]]\nname = "{c}"\nsource = "{c}"\n' for c in ("cam01", "cam02"))
    path = folder / "config.toml"
    path.write_text(
        f'calibration = "calib.toml"\nsite = "site.toml"\noutput = "{output}"\n{cameras}'
        f"[detector]\nimgsz = 64\n[outputs]\nreport = false\n{extra}"
    )
    return path


def snapshot(root: Path) -> dict[Path, tuple[bytes, int]]:
    return {
        p: (p.read_bytes(), p.stat().st_mtime_ns) for p in sorted(root.rglob("*")) if p.is_file()
    }


def _error(argv: list[str], capsys) -> str:
    assert main(argv) == 2
    captured = capsys.readouterr()
    assert "Traceback" not in captured.out + captured.err
    return " ".join(captured.err.split())


@pytest.mark.parametrize("output", [".", "./", "cam01/.."])
def test_a_run_beside_its_own_files_never_rewrites_them(
    tmp_path: Path, capsys, output: str
) -> None:
    config = _config(tmp_path, output)
    before = snapshot(tmp_path)
    err = _error(["run", str(config)], capsys)
    assert "in the output folder" in err and "an input" in err
    assert str(tmp_path) in err and "set `output`" in err
    assert snapshot(tmp_path) == before  # the calibration, site and configuration untouched


def test_a_run_never_writes_inside_a_camera_s_image_folder(tmp_path: Path, capsys) -> None:
    config = _config(tmp_path, "cam01/out")
    before = snapshot(tmp_path)
    err = _error(["run", str(config)], capsys)
    assert f"inside the cameras[0].source folder {tmp_path / 'cam01'}" in err
    assert snapshot(tmp_path) == before


def test_a_run_folder_holds_one_run(tmp_path: Path, capsys) -> None:
    config = _config(tmp_path, "out", extra="overlays = false\n")
    out = tmp_path / "out"
    assert main(["run", str(config)]) == 0
    capsys.readouterr()
    first = json.loads((out / "summary.json").read_text())
    assert first["frames"] == 2
    # what a previous run with other outputs left, and the user's own file
    (out / "trc").mkdir(exist_ok=True)
    (out / "trc" / "person_7.trc").write_text("a previous run's person\n")
    (out / "overlays").mkdir()
    (out / "overlays" / "cam01.mp4").write_bytes(b"a previous run's video")
    (out / "notes.txt").write_text("mine\n")
    inputs = {p: v for p, v in snapshot(tmp_path).items() if not p.is_relative_to(out)}
    before = snapshot(tmp_path)
    err = _error(["run", str(config)], capsys)
    assert f"{out} already holds a previous run's outputs" in err and "--overwrite" in err
    assert snapshot(tmp_path) == before  # refused: the previous run is kept whole

    assert main(["run", str(config), "--overwrite"]) == 0
    left = {p.relative_to(out).as_posix() for p in out.rglob("*") if p.is_file()}
    assert "notes.txt" in left and (out / "notes.txt").read_text() == "mine\n"
    assert not {"trc/person_7.trc", "overlays/cam01.mp4"} & left
    assert {"poses3d.jsonl", "summary.json", "events.sqlite", "calib.toml"} <= left
    assert {p: v for p, v in snapshot(tmp_path).items() if not p.is_relative_to(out)} == inputs
    second = json.loads((out / "summary.json").read_text())
    assert second["frames"] == 2 and not second["interrupted"]


@pytest.mark.parametrize(
    ("extra", "secret"),
    [
        ("", False),
        ('[mqtt]\nusername = "ops"\npassword = "s3cret"\n', True),
        ('webhook = "http://token@127.0.0.1:9/alarms"\n', True),
    ],
)
def test_the_configuration_copy_is_private_when_it_holds_a_secret(
    tmp_path: Path, capsys, extra: str, secret: bool
) -> None:
    config = _config(tmp_path, "out", extra)  # after [outputs]: its webhook, or a new table
    main(["run", str(config)])  # an unreachable webhook may end it with 3: the copy is made
    capsys.readouterr()
    copy = tmp_path / "out" / "config.toml"
    if not secret:
        assert copy.read_text() == config.read_text()
    else:  # its secrets masked: the copy (and the report showing it) never holds them
        assert "s3cret" not in copy.read_text() and "token@" not in copy.read_text()
        assert copy.read_text().count("\n") == config.read_text().count("\n")
        assert 'password = "<hidden>"' in copy.read_text() or "***@127.0.0.1" in copy.read_text()
    assert (copy.stat().st_mode & 0o077 == 0) is secret
