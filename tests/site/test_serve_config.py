"""`stereopose serve`: a bad configuration is exit 2 before any work, naming the file and key."""

from __future__ import annotations

from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from stereopose.calibration.formats import save_calibration
from stereopose.cli import main
from stereopose.sim import simulate


@pytest.fixture(scope="module")
def calib(tmp_path_factory) -> Path:
    scene = simulate(num_cameras=2, num_people=1, num_frames=2, seed=1, difficulty="easy")
    path = tmp_path_factory.mktemp("calib") / "calib.toml"
    save_calibration(path, scene.rig)
    return path


def _config(folder: Path, calib: Path, extra: str, source: str = "cam.mp4") -> Path:
    from stereopose.calibration.formats import load_calibration

    names = load_calibration(calib).names
    cams = "".join(f'[[cameras]]\nname = "{n}"\nsource = "{source}"\n\n' for n in names)
    path = folder / "serve.toml"
    path.write_text(f'calibration = "{calib}"\noutput = "out"\n\n{extra}\n\n{cams}')
    return path


BAD = [
    ('[mqtt]\nhost = "localhost"\ntopic_prefix = "$SYS"', "mqtt.topic_prefix"),
    ('[mqtt]\nhost = "localhost"\npassword = "x"', "mqtt.password"),
    ('[mqtt]\nhost = "localhost"\nca_file = "ca.pem"', "mqtt.ca_file"),
    ("[mqtt]\nport = 0", "mqtt.port"),
    ("[mqtt]\nqueue_size = 0", "mqtt.queue_size"),
    ('[mqtt]\nhots = "x"', "hots"),
    ("[serve]\nport = 70000", "serve.port"),
    ('[serve]\nhost = "not a host!"', "serve.host"),
    ("[serve]\ncamera_timeout_s = 0", "serve.camera_timeout_s"),
    ("[serve]\ncalib_warn_factor = 1.0", "serve.calib_warn_factor"),
    ("[storage]\nretention_days = 0", "storage.retention_days"),
    ("[storage]\nmax_gb = -1", "storage.max_gb"),
    ("[storage]\nclip_pre_s = 100", "storage.clip_pre_s"),
    ('[outputs]\nwebhook = "ftp://x"', "outputs.webhook"),
    ("[input]\ndetect_fps = 0", "input.detect_fps"),
    ('[detector]\nprecision = "int4"', "detector.precision"),
]


@pytest.mark.parametrize(("extra", "key"), BAD, ids=[k for _, k in BAD])
def test_bad_setting_is_exit_2_naming_the_key(tmp_path, calib, capsys, extra, key):
    path = _config(tmp_path, calib, extra)
    assert main(["serve", str(path)]) == 2
    err = capsys.readouterr().err.replace("\n", "")
    assert key in err and str(path.name) in err
    assert not (tmp_path / "out").exists()  # nothing written


def test_a_stream_cannot_be_looped(tmp_path, calib, capsys):
    path = _config(tmp_path, calib, "", source="rtsp://10.0.0.5/cam")
    text = path.read_text().replace(
        'source = "rtsp://10.0.0.5/cam"\n', 'source = "rtsp://10.0.0.5/cam"\nloop = true\n', 1
    )
    path.write_text(text)
    assert main(["serve", str(path)]) == 2
    assert "cameras[0].loop" in capsys.readouterr().err


def test_output_inside_an_input_folder_is_refused(tmp_path, calib, capsys):
    images = tmp_path / "images"
    images.mkdir()
    path = _config(tmp_path, calib, "", source=str(images))
    path.write_text(path.read_text().replace('output = "out"', f'output = "{images}"'))
    assert main(["serve", str(path)]) == 2
    err = capsys.readouterr().err.replace("\n", "")
    assert "cameras[0].source" in err and "output" in err
    assert list(images.iterdir()) == []


def test_needs_a_config_or_the_demo(capsys):
    assert main(["serve"]) == 2
    assert "--demo" in capsys.readouterr().err


@settings(max_examples=25, deadline=None)
@given(port=st.one_of(st.integers(max_value=-1), st.integers(min_value=65536)))
def test_any_port_out_of_range_is_refused(tmp_path_factory, calib, port):
    folder = tmp_path_factory.mktemp("port")
    path = _config(folder, calib, f"[serve]\nport = {port}")
    assert main(["serve", str(path)]) == 2
    assert main(["serve", str(_config(folder, calib, "")), "--port", str(port)]) == 2


def _secret(folder: Path, text: str = "s3cret\n", mode: int = 0o600) -> Path:
    path = folder / "mqtt.secret"
    path.write_text(text)
    path.chmod(mode)
    return path


MQTT = '[mqtt]\nhost = "localhost"\nusername = "ops"\n'


def test_the_mqtt_password_can_come_from_a_private_file(tmp_path, calib):
    from stereopose.site.plan import plan_serve

    _secret(tmp_path)
    path = _config(tmp_path, calib, MQTT + 'password_file = "mqtt.secret"')
    plan = plan_serve(path)
    assert plan.mqtt is not None and plan.mqtt.password == "s3cret"
    assert "s3cret" not in path.read_text() and "s3cret" not in repr(plan)


@pytest.mark.parametrize(
    ("extra", "secret", "problem"),
    [
        ('password = "x"\npassword_file = "mqtt.secret"', ("s3cret\n", 0o600), "give one of"),
        ('password_file = "mqtt.secret"', ("s3cret\n", 0o644), "readable by every user"),
        ('password_file = "mqtt.secret"', ("\n", 0o600), "is empty"),
        ('password_file = "nothing.secret"', ("s3cret\n", 0o600), "cannot read"),
        ('password_file = "."', ("s3cret\n", 0o600), "not a small regular file"),
    ],
)
def test_a_bad_password_file_is_exit_2_naming_it(tmp_path, calib, capsys, extra, secret, problem):
    _secret(tmp_path, *secret)
    path = _config(tmp_path, calib, MQTT + extra)
    assert main(["serve", str(path)]) == 2
    err = " ".join(capsys.readouterr().err.split())
    assert "mqtt.password" in err and problem in err and "s3cret" not in err
    assert not (tmp_path / "out").exists()


def test_demo_config_keeps_the_port_given(tmp_path):
    import argparse

    from stereopose.cli.serve import _config_path

    for port, want in ((19500, 19500), (None, 8787)):
        args = argparse.Namespace(
            demo=True, config=None, out=tmp_path / str(port), data=None, port=port
        )
        text = _config_path(args).read_text()
        assert f'\n[serve]\nhost = "127.0.0.1"\nport = {want}\n' in text


def test_the_service_says_which_interfaces_are_on_and_warns_of_one_left_off(tmp_path):
    from stereopose.config import load_config
    from stereopose.site.plan import disabled_settings, interfaces

    path = tmp_path / "serve.toml"
    path.write_text(
        '[mqtt]\nhost = "127.0.0.1"\nport = 1884\n\n'
        '[iec104]\nhost = "10.0.0.5"\nport = 2405\n\n'
        "[opcua]\nenabled = true\n"
    )
    cfg = load_config(path)
    assert interfaces(cfg) == [
        "MQTT on 127.0.0.1:1884 (site site)",
        "webhook off",
        "IEC 104 off",
        "OPC UA on opc.tcp://127.0.0.1:4840/stereopose",
        "warnings on site off",
    ]
    from stereopose.fence.site import parse_site

    zone = {"name": "bus", "kind": "energized", "polygon": [[0, 0], [1, 0], [1, 1]], "z": [0, 2]}
    speaker = {"name": "pa", "url": "rtp://239.1.1.1:5004", "zones": ["bus"]}
    site = parse_site({"zones": [zone], "speakers": [speaker]})
    assert interfaces(cfg, site)[-1] == "warnings on site: 1 speaker(s), 0 signal(s)"
    (warning,) = disabled_settings(cfg)
    assert warning.startswith("[iec104] sets host, port but not enabled = true")
    assert "set [iec104] enabled = true" in warning
    assert disabled_settings(load_config(None)) == []  # sections left alone: nothing to say


def _corrected(calib: Path, folder: Path, moved: float, source: Path | None = None) -> Path:
    """A correction of `calib` as the calibration keeper writes it, in `folder`."""
    import dataclasses

    import numpy as np

    from stereopose.calibration.formats import load_calibration
    from stereopose.types import Rig

    rig = load_calibration(calib)
    first = rig[rig.names[0]]
    new = dataclasses.replace(first, translation=np.add(first.translation, [moved, 0.0, 0.0]))
    fixed = Rig(tuple(new if c.name == first.name else c for c in rig))
    path = folder / "calib.corrected.toml"
    save_calibration(path, fixed, {"corrected_from": str(source or calib), "camera": first.name})
    return path


def test_a_restart_keeps_the_services_correction_of_the_calibration(tmp_path, calib, caplog):
    import os

    from stereopose.site.plan import plan_serve

    own = tmp_path / "calib.toml"
    own.write_bytes(calib.read_bytes())
    before = plan_serve(_config(tmp_path, own, ""))
    assert before.calib_loaded == own
    x0 = before.rig[before.rig.names[0]].translation[0]
    # corrected beside it (newer): loaded, and said
    fixed = _corrected(own, tmp_path, 0.25)
    plan = plan_serve(_config(tmp_path, own, ""))
    assert plan.calib_loaded == fixed and plan.calib_path == own
    assert plan.rig[plan.rig.names[0]].translation[0] == pytest.approx(x0 + 0.25)
    assert "correction of" in caplog.text
    # unless told not to
    off = plan_serve(_config(tmp_path, own, "[serve]\ncalibration_corrected = false"))
    assert off.calib_loaded == own
    # in the output folder when it is newer still
    out = tmp_path / "out"
    out.mkdir()
    later = _corrected(own, out, 0.5)
    os.utime(later, (fixed.stat().st_mtime + 5, fixed.stat().st_mtime + 5))
    assert plan_serve(_config(tmp_path, own, "")).calib_loaded == later
    # the original calibrated again since: the original wins
    t = later.stat().st_mtime + 10
    os.utime(own, (t, t))
    assert plan_serve(_config(tmp_path, own, "")).calib_loaded == own
    # a correction of another file, or a broken one, is not used
    os.utime(own, (t - 20, t - 20))
    _corrected(own, out, 0.5, source=tmp_path / "other.toml")
    fixed.write_text("[cam01\n")
    caplog.clear()
    assert plan_serve(_config(tmp_path, own, "")).calib_loaded == own
    assert "not corrected from" in caplog.text and "is not used" in caplog.text
