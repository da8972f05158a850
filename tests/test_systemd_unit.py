"""packaging/stereopose.service: a unit systemd accepts, that keeps serve running, stops it
with SIGTERM and confines it to its own folders."""

from __future__ import annotations

import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

UNIT = Path(__file__).resolve().parents[1] / "packaging" / "stereopose.service"


def parse_unit(text: str) -> dict[str, dict[str, list[str]]]:
    """Section -> key -> its values in order (a key may repeat, as Environment= does); comments,
    blank lines and continuation lines as systemd reads them."""
    sections: dict[str, dict[str, list[str]]] = {}
    current: dict[str, list[str]] | None = None
    logical, pending = [], ""
    for raw in text.splitlines():
        line = raw.strip()
        if not pending and (not line or line[0] in "#;"):
            continue
        if line.endswith("\\"):
            pending += line[:-1].rstrip() + " "
            continue
        logical.append(pending + line)
        pending = ""
    assert not pending, "the unit ends inside a continued line"
    for line in logical:
        if line.startswith("[") and line.endswith("]"):
            current = sections.setdefault(line[1:-1], {})
            continue
        key, sep, value = line.partition("=")
        assert sep and current is not None, f"not a key=value line in a section: {line!r}"
        current.setdefault(key.strip(), []).append(value.strip())
    return sections


@pytest.fixture(scope="module")
def unit() -> dict[str, dict[str, list[str]]]:
    return parse_unit(UNIT.read_text(encoding="utf-8"))


def _one(unit, section: str, key: str) -> str:
    values = unit[section].get(key)
    assert values, f"[{section}] {key}= missing"
    return values[-1]


def test_the_parser_reads_repeated_keys_and_continuations() -> None:
    u = parse_unit("# c\n[A]\nX=1\nX=2 \\\n  3\n; c\n[B]\nY=\n")
    assert u == {"A": {"X": ["1", "2 3"]}, "B": {"Y": [""]}}
    with pytest.raises(AssertionError):
        parse_unit("X=1\n")


def test_serve_runs_as_its_own_user_and_is_always_restarted(unit) -> None:
    s = "Service"
    assert _one(unit, s, "Type") in ("simple", "exec", "notify")
    assert _one(unit, s, "Restart") == "always"
    assert float(_one(unit, s, "RestartSec")) > 0
    assert _one(unit, "Unit", "StartLimitIntervalSec") == "0"  # never gives up
    assert _one(unit, s, "User") not in ("", "root", "0")
    assert _one(unit, s, "WorkingDirectory").startswith("/")
    assert _one(unit, "Install", "WantedBy") == "multi-user.target"


def test_exec_start_is_a_serve_command_line_the_cli_accepts(unit) -> None:
    argv = shlex.split(_one(unit, "Service", "ExecStart"))
    assert Path(argv[0]).is_absolute() and argv[0].endswith("/bin/stereopose")
    assert argv[1:] == ["serve", "/etc/stereopose/serve.toml"]
    from stereopose.cli import COMMANDS, build_parser

    if "serve" not in COMMANDS:
        pytest.skip("the serve command does not exist yet")
    args = build_parser().parse_args(argv[1:])
    assert args.command == "serve"


def test_it_is_stopped_by_sigterm_within_a_bound(unit) -> None:
    assert _one(unit, "Service", "KillSignal") == "SIGTERM"
    assert 5 <= float(_one(unit, "Service", "TimeoutStopSec")) <= 120


def test_it_writes_only_its_own_folders_and_secrets_come_from_root_only_files(unit) -> None:
    s = unit["Service"]
    for key, value in (
        ("NoNewPrivileges", "yes"),
        ("ProtectSystem", "strict"),
        ("PrivateTmp", "yes"),
        ("ProtectHome", "yes"),
    ):
        assert _one(unit, "Service", key) == value, key
    writable = " ".join(s["ReadWritePaths"]).split()
    assert _one(unit, "Service", "WorkingDirectory") in writable
    state = "/var/lib/" + _one(unit, "Service", "StateDirectory")
    assert state in writable
    # the models come from a cache the service reads and cannot change
    env = dict(e.split("=", 1) for v in s["Environment"] for e in shlex.split(v))
    cache = env["STEREOPOSE_CACHE"]
    assert cache.startswith("/") and not any(cache.startswith(w) for w in writable)
    # numba's cache is writable, or each start would compile the 3D loops again
    assert env["NUMBA_CACHE_DIR"].startswith(
        "/var/cache/" + _one(unit, "Service", "CacheDirectory")
    )
    assert any(f.lstrip("-").startswith("/etc/stereopose/") for f in s["EnvironmentFile"])
    # numba and ONNX Runtime write machine code at run time
    assert "MemoryDenyWriteExecute" not in s


@pytest.mark.skipif(shutil.which("systemd-analyze") is None, reason="no systemd-analyze")
def test_systemd_analyze_verifies_the_unit_without_a_warning(tmp_path: Path) -> None:
    # verify checks that ExecStart exists: point it at this install's command
    here = Path(sys.executable).parent / "stereopose"
    assert here.is_file()
    text = UNIT.read_text(encoding="utf-8")
    argv0 = shlex.split(_one(parse_unit(text), "Service", "ExecStart"))[0]
    copy = tmp_path / UNIT.name
    copy.write_text(text.replace(argv0, str(here)), encoding="utf-8")
    proc = subprocess.run(
        ["systemd-analyze", "verify", str(copy)], capture_output=True, text=True, timeout=60
    )
    about_it = [line for line in (proc.stdout + proc.stderr).splitlines() if UNIT.name in line]
    assert proc.returncode == 0 and not about_it, proc.stdout + proc.stderr


NODE_UNIT = UNIT.with_name("stereopose-node@.service")


def test_a_node_unit_runs_the_nodes_own_entry_and_is_always_restarted() -> None:
    unit = parse_unit(NODE_UNIT.read_text(encoding="utf-8"))
    assert _one(unit, "Service", "Restart") == "always"
    assert _one(unit, "Unit", "StartLimitIntervalSec") == "0"
    assert _one(unit, "Service", "User") not in ("", "root", "0")
    assert _one(unit, "Service", "KillSignal") == "SIGTERM"
    for key, value in (
        ("NoNewPrivileges", "yes"),
        ("ProtectSystem", "strict"),
        ("PrivateTmp", "yes"),
        ("ProtectHome", "yes"),
    ):
        assert _one(unit, "Service", key) == value, key
    assert "ReadWritePaths" not in unit["Service"]  # a node writes no file
    argv = shlex.split(_one(unit, "Service", "ExecStart").replace("%i", "node-a"))
    assert argv[1:] == ["detect-node", "/etc/stereopose/serve.toml", "--node", "node-a"]
    from stereopose.cli import build_parser

    args = build_parser().parse_args(argv[1:])
    assert (args.command, args.node) == ("detect-node", "node-a")


@pytest.mark.skipif(shutil.which("systemd-analyze") is None, reason="no systemd-analyze")
def test_systemd_analyze_verifies_a_node_instance_without_a_warning(tmp_path: Path) -> None:
    here = Path(sys.executable).parent / "stereopose"
    text = NODE_UNIT.read_text(encoding="utf-8")
    argv0 = shlex.split(_one(parse_unit(text), "Service", "ExecStart"))[0]
    copy = tmp_path / "stereopose-node@node-a.service"
    copy.write_text(text.replace(argv0, str(here)), encoding="utf-8")
    proc = subprocess.run(
        ["systemd-analyze", "verify", str(copy)], capture_output=True, text=True, timeout=60
    )
    about_it = [line for line in (proc.stdout + proc.stderr).splitlines() if "stereopose" in line]
    assert proc.returncode == 0 and not about_it, proc.stdout + proc.stderr
