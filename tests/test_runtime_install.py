"""The runtime install (an edge box's: the package and its base dependencies, no PyTorch).

`serve` and everything it imports must load without torch and without the offline tools'
extras (scipy, matplotlib), and must not load torch even where it is installed. plotly is a
base dependency (the operator console serves its plotly.min.js), yet no serve module imports
its Python side.
Each check runs in a fresh interpreter, so what other tests imported does not count.
"""

from __future__ import annotations

import importlib.metadata
import json
import os
import re
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SRC = ROOT / "src"
RUNTIME_PYTHON = ROOT / ".venv-runtime" / "bin" / "python"

# never in the runtime install (each is hundreds of MB, or needed only by the offline tools)
HEAVY = frozenset({"torch", "torchvision", "triton", "ultralytics"})
EXTRAS_ONLY = frozenset({"scipy", "matplotlib"})
# installed with the base (plotly: the console's plotly.min.js), never imported by serve
NOT_IMPORTED = HEAVY | EXTRAS_ONLY | {"plotly"}

# what serve imports beyond the service package, by module name (each must exist: a renamed
# module fails here, never passes silently)
SERVE_MODULES = (
    "stereopose.cli.serve",
    "stereopose.pipeline.pipelined",
    "stereopose.io.sinks.mqtt",
    "stereopose.io.sinks.mqtt_settings",
    "stereopose.io.sinks.segments",
    "stereopose.io.sinks.clips",
    "stereopose.viz.clips",
    "stereopose.detection.yolo_onnx",
    "stereopose.calibration.refine",  # a drifted camera placed again (site.health.calib_keeper)
)


def _modules_of(package: str, at_least: int) -> tuple[str, ...]:
    """Every module of stereopose.<package>, read from the tree, whatever is added to it
    later."""
    names = []
    for path in sorted((SRC / "stereopose" / package).rglob("*.py")):
        parts = path.relative_to(SRC).with_suffix("").parts
        names.append(".".join(parts[:-1] if parts[-1] == "__init__" else parts))
    assert len(names) >= at_least, f"stereopose.{package}: too few modules found (moved?)"
    return tuple(names)


# the site service (its HTTP layer and health), and the HTTP kit it is served with
MODULES = SERVE_MODULES + _modules_of("site", 20) + _modules_of("web", 8)

# Prepended to the child's code: the packages named in argv[1] are unimportable there, as in a
# runtime install.
BLOCK = """
import importlib, json, sys
blocked = set(json.loads(sys.argv[1]))
class Block:
    def find_spec(self, name, path=None, target=None):
        if name.partition(".")[0] in blocked:
            raise ModuleNotFoundError(f"No module named {name!r}", name=name)
        return None
sys.meta_path.insert(0, Block())
"""

# Import each module in turn and report, per module, its error or the heavy packages that
# arrived with it.
PROBE = (
    BLOCK
    + """
heavy, modules = json.loads(sys.argv[2])
result = {}
for m in modules:
    before = set(sys.modules)
    try:
        importlib.import_module(m)
    except BaseException as e:
        result[m] = {"error": f"{type(e).__name__}: {e}"}
        continue
    arrived = {n.partition(".")[0] for n in set(sys.modules) - before}
    result[m] = {"heavy": sorted(arrived & set(heavy))}
print(json.dumps(result))
"""
)


def _probe(python: Path | str, modules: list[str], blocked: frozenset[str]) -> dict[str, dict]:
    """Per module: {"error": ...} or {"heavy": the HEAVY packages its import loaded}. (numba
    loads scipy where it is installed, to check its version: that does not count.)"""
    env = {**os.environ, "PYTHONPATH": str(SRC)} if python == sys.executable else dict(os.environ)
    args = [json.dumps(sorted(blocked)), json.dumps([sorted(HEAVY), modules])]
    proc = subprocess.run(
        [str(python), "-c", PROBE, *args],
        capture_output=True,
        text=True,
        timeout=120,
        env=env,
        cwd=ROOT,
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    return json.loads(proc.stdout.strip().splitlines()[-1])


def _exists(module: str) -> bool:
    base = SRC.joinpath(*module.split("."))
    return base.with_suffix(".py").is_file() or (base / "__init__.py").is_file()


@pytest.fixture(scope="module")
def loaded() -> dict[str, dict]:
    """Each serve module imported where torch is installed: what came with it."""
    return _probe(sys.executable, [m for m in MODULES if _exists(m)], frozenset())


@pytest.fixture(scope="module")
def runtime_like() -> dict[str, dict]:
    """Each serve module imported with the runtime's missing packages unimportable."""
    return _probe(sys.executable, [m for m in MODULES if _exists(m)], NOT_IMPORTED)


def _present(module: str) -> None:
    assert _exists(module), f"{module}: no such module (renamed? update SERVE_MODULES)"


@pytest.mark.parametrize("module", MODULES)
def test_the_serve_path_loads_no_torch_even_where_it_is_installed(loaded, module: str) -> None:
    _present(module)
    r = loaded[module]
    assert "error" not in r, r
    assert not r["heavy"], f"importing {module} loads {r['heavy']}"


@pytest.mark.parametrize("module", MODULES)
def test_the_serve_path_imports_without_torch_and_the_offline_extras(
    runtime_like, module: str
) -> None:
    _present(module)
    r = runtime_like[module]
    assert "error" not in r, f"{module} in a runtime install: {r['error']}"


def _requirement_names(requirements: list[str]) -> set[str]:
    """Base requirements (no extra marker) as normalised project names."""
    names = set()
    for req in requirements:
        if "extra ==" in req:
            continue
        name = re.match(r"[A-Za-z0-9][A-Za-z0-9._-]*", req.strip())
        assert name, req
        names.add(re.sub(r"[-_.]+", "-", name.group(0)).lower())
    return names


def test_no_base_requirement_is_heavy_in_pyproject_or_the_installed_metadata() -> None:
    project = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]
    declared = _requirement_names(project["dependencies"])
    installed = _requirement_names(importlib.metadata.requires("stereopose") or [])
    for names in (declared, installed):
        assert "onnxruntime" in names  # the default detector's runtime
        assert not names & (HEAVY | EXTRAS_ONLY), names & (HEAVY | EXTRAS_ONLY)
        assert not {n for n in names if n.startswith("nvidia-")}
        assert "plotly" in names  # the console's 3D view, served from the package's bundle
    # and the development install keeps everything, through its extras
    extras = project["optional-dependencies"]
    assert "report" in extras  # kept as a name: `pip install 'stereopose[report]'` still works
    for extra, needed in (("ultralytics", "torch"), ("calibration", "scipy")):
        assert needed in _requirement_names(extras[extra]), extra


# The CLI with the packages of argv[1] unimportable, on the arguments of argv[2].
CLI = (
    BLOCK
    + """
from stereopose.cli import main
code = main(json.loads(sys.argv[2]))
assert not blocked & set(sys.modules)
sys.exit(code)
"""
)


def _cli(args: list[str], blocked: frozenset[str]) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-c", CLI, json.dumps(sorted(blocked)), json.dumps(args)],
        capture_output=True,
        text=True,
        timeout=120,
        env={**os.environ, "PYTHONPATH": str(SRC), "COLUMNS": "200"},
    )


def test_serve_help_runs_without_torch_and_the_offline_extras() -> None:
    from stereopose.cli import COMMANDS

    assert "serve" in COMMANDS
    proc = _cli(["serve", "--help"], NOT_IMPORTED)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "usage: stereopose serve" in proc.stdout


@pytest.mark.parametrize(
    ("args", "missing", "extra"),
    [
        (["report", "RUN_DIR"], "plotly", "report"),
        (
            [
                "calibrate",
                "extrinsics",
                "--images",
                "IMAGES",
                "--intrinsics",
                "CALIB.toml",
                "--board",
                "4x3",
                "--square",
                "0.1",
                "--out",
                "OUT.toml",
            ],
            "scipy",
            "calibration",
        ),
        (
            [
                "calibrate",
                "intrinsics",
                "--images",
                "IMAGES",
                "--board",
                "4x3",
                "--square",
                "0.1",
                "--out",
                "OUT.toml",
                "--report",
                "PICTURES",
            ],
            "matplotlib",
            "calibration",
        ),
    ],
)
def test_a_command_needing_a_missing_extra_says_which_to_install(
    tmp_path: Path, args: list[str], missing: str, extra: str
) -> None:
    args = [str(tmp_path / a) if a.isupper() and a.replace(".", "").isalpha() else a for a in args]
    proc = _cli(args, HEAVY | {missing})
    assert proc.returncode == 2, proc.stdout + proc.stderr
    text = " ".join((proc.stdout + proc.stderr).split())
    assert f"needs {missing}" in text
    assert f"pip install 'stereopose[{extra}]'" in text
    assert "Traceback" not in text
    assert not list(tmp_path.iterdir())  # refused before any work


def test_the_report_of_a_run_is_refused_before_the_run_when_plotly_is_missing(
    tmp_path: Path,
) -> None:
    code = (
        "from stereopose.pipeline.outputs import ReportSink\n"
        "from stereopose.extras import MissingExtraError\n"
        f"try:\n    ReportSink({str(tmp_path)!r}, None)\n"
        "except MissingExtraError as e:\n    print(e)\nelse:\n    raise SystemExit(1)\n"
    )
    run = subprocess.run(
        [sys.executable, "-c", BLOCK + code, json.dumps(["plotly"])],
        capture_output=True,
        text=True,
        timeout=120,
        env={**os.environ, "PYTHONPATH": str(SRC)},
    )
    assert run.returncode == 0, run.stdout + run.stderr
    assert "report = false" in run.stdout
    assert not list(tmp_path.iterdir())


@pytest.mark.skipif(not RUNTIME_PYTHON.is_file(), reason="no .venv-runtime (make runtime)")
def test_the_runtime_venv_has_no_torch_and_loads_the_serve_path() -> None:
    """`make runtime`'s venv, where it was built: torch is not even installed there, and every
    serve module that venv's copy of the package holds imports."""
    proc = subprocess.run(
        [
            str(RUNTIME_PYTHON),
            "-c",
            "import importlib.util as u, json; "
            f"print(json.dumps([n for n in {sorted(HEAVY | EXTRAS_ONLY)!r} if u.find_spec(n)]))",
        ],
        capture_output=True,
        text=True,
        timeout=60,
        cwd="/",
    )
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout) == []
    listed = subprocess.run(
        [
            str(RUNTIME_PYTHON),
            "-c",
            "import importlib.util as u, json, sys; "
            "print(json.dumps([m for m in json.loads(sys.argv[1]) if u.find_spec(m)]))",
            json.dumps(list(MODULES)),
        ],
        capture_output=True,
        text=True,
        timeout=60,
        cwd="/",
    )
    assert listed.returncode == 0, listed.stderr
    have = json.loads(listed.stdout)
    assert "stereopose.detection.yolo_onnx" in have
    result = _probe(RUNTIME_PYTHON, have, frozenset())
    assert all("error" not in r and not r["heavy"] for r in result.values()), result


def test_making_the_int8_model_without_onnx_says_which_extra_or_which_file_to_copy(
    tmp_path: Path,
) -> None:
    code = (
        "from pathlib import Path\n"
        "from stereopose.detection.models import quantize_int8\n"
        "from stereopose.extras import MissingExtraError\n"
        f"try:\n    quantize_int8(out=Path({str(tmp_path / 'm-int8.onnx')!r}))\n"
        "except MissingExtraError as e:\n    print(e)\nelse:\n    raise SystemExit(1)\n"
    )
    run = subprocess.run(
        [sys.executable, "-c", BLOCK + code, json.dumps(["onnx"])],
        capture_output=True,
        text=True,
        timeout=120,
        env={**os.environ, "PYTHONPATH": str(SRC)},
    )
    assert run.returncode == 0, run.stdout + run.stderr
    assert "pip install 'stereopose[int8]'" in run.stdout
    assert str(tmp_path / "m-int8.onnx") in run.stdout
    assert not list(tmp_path.iterdir())
