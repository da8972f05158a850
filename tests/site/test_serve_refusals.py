"""A start `serve` refuses leaves nothing behind: each refusal the commands' docs list (a bad
value, the port taken, an event log that cannot be read, an address other machines reach with
no user) is exit 2 with its message, and no file or folder is made (a data folder that was
there is left as it was)."""

from __future__ import annotations

import socket
import subprocess
import sys
from pathlib import Path

import pytest

from brokers import free_port
from stereopose.pipeline.demo import write_serve_demo_config

pytestmark = pytest.mark.realdata


def _serve(config: Path) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "stereopose.cli", "serve", str(config)],
        capture_output=True,
        text=True,
        timeout=180,
    )


def _files(folder: Path) -> dict[str, int]:
    return {str(p.relative_to(folder)): p.stat().st_size for p in folder.rglob("*")}


def _config(tmp_path: Path, port: int) -> tuple[Path, Path]:
    data = tmp_path / "data"
    return write_serve_demo_config(tmp_path / "demo", data, port, imgsz=320), data


def test_a_taken_port_is_refused_before_any_file(tmp_path):
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen(1)
        config, data = _config(tmp_path, taken.getsockname()[1])
        done = _serve(config)
    assert done.returncode == 2, done.stdout + done.stderr
    assert "Address already in use" in done.stdout + done.stderr
    assert not data.exists(), _files(data)


def test_a_bad_value_is_refused_before_any_file(tmp_path):
    config, data = _config(tmp_path, free_port())
    config.write_text(
        config.read_text().replace("[serve]\n", "[serve]\nstatus_interval_s = -1\n", 1)
    )
    done = _serve(config)
    assert done.returncode == 2 and "status_interval_s" in done.stdout + done.stderr
    assert not data.exists()


def test_an_unreadable_event_log_is_refused_and_the_folder_left_as_it_was(tmp_path):
    config, data = _config(tmp_path, free_port())
    data.mkdir()
    (data / "events.sqlite").write_bytes(b"not a database at all " * 64)
    before = _files(data)
    done = _serve(config)
    assert done.returncode == 2 and "events.sqlite" in done.stdout + done.stderr
    assert _files(data) == before


def test_an_open_address_without_a_user_is_refused_before_any_file(tmp_path):
    config, data = _config(tmp_path, free_port())
    config.write_text(config.read_text().replace('host = "127.0.0.1"', 'host = "0.0.0.0"', 1))
    done = _serve(config)
    assert done.returncode == 2, done.stdout + done.stderr
    assert "user" in done.stdout + done.stderr
    assert not data.exists(), _files(data)
