"""`calibrate points`, `people` and `refine` from the command line on a simulated yard
written as a user's files: the calibration written and read back, and bad input answered by
exit 2 naming the file and the reason."""

from __future__ import annotations

import numpy as np
import pytest

from stereopose.calibration.formats import load_calibration, save_calibration
from stereopose.cli import main
from stereopose.detection.openpose import write_pose_frame
from stereopose.sim.yard import bump, rig_errors, survey, yard_scene
from stereopose.types import Camera, Rig

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def site(tmp_path_factory):
    """A yard's files: intrinsics.toml, true.toml, points.toml, pose/<camera>_json."""
    root = tmp_path_factory.mktemp("yard")
    yard = yard_scene(seed=4, walkers=1, duration_s=40.0)
    bare = Rig(
        tuple(
            Camera(c.name, c.size, c.matrix, c.distortions, [0, 0, 0], [0, 0, 1]) for c in yard.rig
        )
    )
    save_calibration(root / "intrinsics.toml", bare)
    save_calibration(root / "true.toml", yard.rig)
    for t in range(0, len(yard.detections), 4):
        for people in yard.detections[t].values():
            write_pose_frame(root / "pose", people.camera, people)
    world, clicks = survey(yard.rig, np.random.default_rng(1))
    lines = ["[points]"] + [f"{p} = [{x:.4f}, {y:.4f}, {z:.4f}]" for p, (x, y, z) in world.items()]
    for cam, seen in clicks.items():
        lines.append(f"[cameras.{cam}]")
        lines += [f"{p} = [{u:.2f}, {v:.2f}]" for p, (u, v) in seen.items()]
    (root / "points.toml").write_text("\n".join(lines) + "\n")
    return root, yard


def test_points_then_people_then_refine(site, tmp_path, capsys) -> None:
    root, yard = site
    out = tmp_path / "points.toml"
    args = ["calibrate", "points", "--points", str(root / "points.toml")]
    assert main([*args, "--intrinsics", str(root / "intrinsics.toml"), "--out", str(out)]) == 0
    rig = load_calibration(out)
    assert max(rig_errors(rig, yard.rig)["rotation_deg"].values()) < 0.3
    d = np.linalg.norm(yard.rig["cam01"].center - yard.rig["cam03"].center)
    people = tmp_path / "people.toml"
    code = main(
        [
            "calibrate",
            "people",
            "--pose",
            str(root / "pose"),
            "--intrinsics",
            str(root / "intrinsics.toml"),
            "--out",
            str(people),
            "--distance",
            "cam01",
            "cam03",
            f"{d:.4f}",
            "--report",
            str(tmp_path / "report"),
        ]
    )
    said = capsys.readouterr()
    assert code == 0, said
    assert "one recording: no held-out check" in said.out  # how to get one is said
    e = rig_errors(load_calibration(people), yard.rig)
    assert np.median(list(e["rotation_deg"].values())) < 0.1 and abs(e["scale"] - 1) < 0.01
    assert (tmp_path / "report" / "people.json").is_file()
    # a bumped camera found by itself (no --cameras) and placed again; the others kept
    knocked = Rig(
        tuple(
            bump(c, np.random.default_rng(3), 1.5, 0.3) if c.name == "cam05" else c
            for c in yard.rig
        )
    )
    save_calibration(tmp_path / "knocked.toml", knocked)
    fixed = tmp_path / "fixed.toml"
    args = ["calibrate", "refine", "--calib", str(tmp_path / "knocked.toml")]
    assert main([*args, "--pose", str(root / "pose"), "--out", str(fixed)]) == 0
    assert "camera cam05: the others place it" in capsys.readouterr().out
    e = rig_errors(load_calibration(fixed), yard.rig)
    assert max(e["rotation_deg"].values()) < 0.1, e


def _people(root, tmp_path, pose, *scale) -> int:
    return main(
        [
            "calibrate",
            "people",
            "--pose",
            str(pose),
            "--intrinsics",
            str(root / "intrinsics.toml"),
            "--out",
            str(tmp_path / "o.toml"),
            *scale,
        ]
    )


def test_too_few_points_places_the_others_and_is_exit_3_naming_the_camera(
    site, tmp_path, capsys
) -> None:
    root, yard = site
    text = (root / "points.toml").read_text()
    head, cams = text.split("[cameras.cam01]")
    cam01, rest = cams.split("[cameras.cam02]")
    short = (
        head + "[cameras.cam01]" + "".join(cam01.splitlines(True)[:4]) + "[cameras.cam02]" + rest
    )
    (tmp_path / "p.toml").write_text(short)
    args = ["calibrate", "points", "--points", str(tmp_path / "p.toml")]
    out = tmp_path / "o.toml"
    code = main([*args, "--intrinsics", str(root / "intrinsics.toml"), "--out", str(out)])
    said = capsys.readouterr()
    text = " ".join((said.out + said.err).split())
    assert code == 3, text
    assert "camera cam01: 3 surveyed point(s) clicked" in text
    assert "calibrate people --points" in text
    placed = load_calibration(out)  # the others, written
    assert "cam01" not in placed.names and len(placed) == len(yard.rig) - 1
    for cam in placed:  # in the points' own frame, as well as with every camera
        true = yard.rig[cam.name]
        turn = np.degrees(np.arccos(np.clip((np.trace(cam.R.T @ true.R) - 1) / 2, -1, 1)))
        assert turn < 0.3 and np.linalg.norm(cam.center - true.center) < 0.15, cam.name


def test_no_people_is_exit_2(site, tmp_path, capsys) -> None:
    root, _ = site
    for cam in ("cam01", "cam02"):
        (tmp_path / "pose" / f"{cam}_json").mkdir(parents=True)
        (tmp_path / "pose" / f"{cam}_json" / f"{cam}_000000000001_keypoints.json").write_text(
            '{"people": []}'
        )
    assert _people(root, tmp_path, tmp_path / "pose", "--height", "1.75") == 2
    assert "no person detected" in capsys.readouterr().err


def test_unsynchronised_folders_are_exit_2(site, tmp_path, capsys) -> None:
    root, _ = site
    import shutil

    pose = tmp_path / "pose"
    shutil.copytree(root / "pose", pose)
    for f in sorted((pose / "cam02_json").iterdir()):  # cam02's numbers shifted far away
        n = int(f.stem.split("_")[1])
        f.rename(f.with_name(f"cam02_{n + 100000:012d}_keypoints.json"))
    assert _people(root, tmp_path, pose, "--height", "1.75") == 2
    err = capsys.readouterr().err
    assert "camera cam02's frames" in err and "not synchronised" in err


def test_a_camera_sharing_no_walker_is_exit_2(site, tmp_path, capsys) -> None:
    root, _ = site
    import shutil

    pose = tmp_path / "pose"
    shutil.copytree(root / "pose", pose)
    for f in (pose / "cam06_json").iterdir():
        f.write_text('{"people": []}')
    assert _people(root, tmp_path, pose, "--height", "1.75") == 2
    assert "cam06 share no walker" in capsys.readouterr().err


def test_a_bad_scale_is_exit_2(site, tmp_path, capsys) -> None:
    root, _ = site
    assert _people(root, tmp_path, root / "pose", "--distance", "cam01", "cam99", "3") == 2
    assert "no camera 'cam99'" in capsys.readouterr().err
    assert _people(root, tmp_path, root / "pose", "--height", "7") == 2
    assert _people(root, tmp_path, root / "pose", "--height", "1.7", "--max-frames", "-3") == 2
    assert "--max-frames: -3" in capsys.readouterr().err
    args = ("--height", "1.7", "--ankle-height", "nan")
    assert _people(root, tmp_path, root / "pose", *args) == 2
    assert "--ankle-height: nan" in capsys.readouterr().err
