"""The package's import graph: no cycles, and imports go down the data flow, never back up."""

from __future__ import annotations

import ast
import textwrap
from collections.abc import Iterable, Mapping
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src"
PACKAGE = "stereopose"
# the top of the data flow: these may import each other and everything below them
TOP = ("pipeline", "cli", "site", "viz", "controlroom", "nodes")


def find_modules(src: Path, package: str) -> dict[str, Path]:
    """Module name -> file for every ``.py`` under ``src/<package>``; ``a/__init__.py`` is ``a``."""
    modules = {}
    for path in sorted((src / package).rglob("*.py")):
        parts = path.relative_to(src).with_suffix("").parts
        if parts[-1] == "__init__":
            parts = parts[:-1]
        modules[".".join(parts)] = path
    return modules


def _within(name: str, package: str) -> bool:
    return name == package or name.startswith(package + ".")


def _known(name: str, modules: Mapping[str, Path]) -> str:
    """The longest prefix of ``name`` that is a module (``a.b.attr`` -> ``a.b``)."""
    parts = name.split(".")
    for n in range(len(parts), 0, -1):
        prefix = ".".join(parts[:n])
        if prefix in modules:
            return prefix
    return name


def _imports(name: str, path: Path, modules: Mapping[str, Path], package: str) -> set[str]:
    """Every module of ``package`` that the module ``name`` imports, wherever the import is."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    here = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found = set()
    for node in ast.walk(tree):  # module level, functions, `if TYPE_CHECKING:` alike
        if isinstance(node, ast.Import):
            found.update(_known(a.name, modules) for a in node.names if _within(a.name, package))
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                parts = here.split(".")
                if node.level - 1 >= len(parts):
                    raise ValueError(f"{path}: relative import beyond the top-level package")
                base = ".".join(parts[: len(parts) - node.level + 1])
                base = f"{base}.{node.module}" if node.module else base
            else:
                base = node.module or ""
            if not _within(base, package):
                continue
            for alias in node.names:
                sub = f"{base}.{alias.name}"
                found.add(sub if sub in modules else _known(base, modules))
    return found


def import_graph(src: Path = SRC, package: str = PACKAGE) -> dict[str, set[str]]:
    """Module -> the package's modules it imports. No implicit edge to a module's parents: only
    imports written in the source count."""
    modules = find_modules(src, package)
    return {name: _imports(name, path, modules, package) for name, path in modules.items()}


def strongly_connected(graph: Mapping[str, Iterable[str]]) -> list[list[str]]:
    """Tarjan's strongly connected components, iteratively (no recursion limit); each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    on_stack: set[str] = set()
    stack: list[str] = []
    components = []
    for root in sorted(graph):
        if root in index:
            continue
        index[root] = low[root] = len(index)
        stack.append(root)
        on_stack.add(root)
        work = [(root, iter(sorted(graph.get(root, ()))))]
        while work:
            node, successors = work[-1]
            for nxt in successors:
                if nxt not in index:
                    index[nxt] = low[nxt] = len(index)
                    stack.append(nxt)
                    on_stack.add(nxt)
                    work.append((nxt, iter(sorted(graph.get(nxt, ())))))
                    break
                if nxt in on_stack:
                    low[node] = min(low[node], index[nxt])
            else:
                work.pop()
                if work:
                    parent = work[-1][0]
                    low[parent] = min(low[parent], low[node])
                if low[node] == index[node]:
                    component = []
                    while True:
                        member = stack.pop()
                        on_stack.discard(member)
                        component.append(member)
                        if member == node:
                            break
                    components.append(sorted(component))
    return sorted(components)


def cycle_report(graph: Mapping[str, Iterable[str]]) -> list[str]:
    """One line per import cycle (its modules) and per module that imports itself."""
    lines = [
        f"import cycle of {len(c)} modules: {', '.join(c)}"
        for c in strongly_connected(graph)
        if len(c) > 1
    ]
    lines += [f"{m} imports itself" for m in sorted(graph) if m in graph[m]]
    return lines


def upward_imports(graph: Mapping[str, Iterable[str]], package: str = PACKAGE) -> list[str]:
    """``importer -> imported`` for each module below the top of the data flow that imports one
    of the top (pipeline, cli, site, viz)."""
    top = tuple(f"{package}.{t}" for t in TOP)
    return [
        f"{m} -> {target}"
        for m in sorted(graph)
        if not any(_within(m, t) for t in top)
        for target in sorted(graph[m])
        if any(_within(target, t) for t in top)
    ]


def test_no_import_cycles() -> None:
    report = cycle_report(import_graph())
    assert not report, "\n".join(report)


def test_imports_go_down_the_data_flow() -> None:
    upward = upward_imports(import_graph())
    assert not upward, "imports up the data flow:\n" + "\n".join(upward)


def test_strongly_connected_components() -> None:
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a", "d"}, "d": {"e"}, "e": {"d", "x"}, "f": set()}
    assert strongly_connected(graph) == [["a", "b", "c"], ["d", "e"], ["f"], ["x"]]
    # a long chain closed into a ring is one component, found without recursion
    ring = {f"m{i:05d}": {f"m{(i + 1) % 5000:05d}"} for i in range(5000)}
    assert strongly_connected(ring) == [sorted(ring)]


def _write_package(root: Path, files: Mapping[str, str]) -> None:
    for rel, text in files.items():
        path = root / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(textwrap.dedent(text), encoding="utf-8")


CLEAN = {
    "fake/__init__.py": "from fake.core import run\n",
    "fake/core.py": """
        import os
        import fake.util.maths
        from fake.util import maths as again
        from fake.util import helper
        from .errors import Oops

        def run():
            from fake import late
    """,
    "fake/late.py": """
        from typing import TYPE_CHECKING

        import numpy as np

        if TYPE_CHECKING:
            from fake.errors import Oops
    """,
    "fake/errors.py": "class Oops(Exception): ...\n",
    "fake/util/__init__.py": "from .maths import helper\nfrom . import maths\n",
    "fake/util/maths.py": "from .. import errors\nfrom ..errors import Oops\n\ndef helper(): ...\n",
    "fake/viz/__init__.py": "from fake.core import run\n",
}


def test_import_graph_of_a_small_package(tmp_path: Path) -> None:
    _write_package(tmp_path, CLEAN)
    assert import_graph(tmp_path, "fake") == {
        "fake": {"fake.core"},
        "fake.core": {"fake.util.maths", "fake.util", "fake.errors", "fake.late"},
        "fake.late": {"fake.errors"},
        "fake.errors": set(),
        "fake.util": {"fake.util.maths"},  # and no edge back from maths to its package
        "fake.util.maths": {"fake.errors"},
        "fake.viz": {"fake.core"},
    }
    assert cycle_report(import_graph(tmp_path, "fake")) == []
    assert upward_imports(import_graph(tmp_path, "fake"), "fake") == []


@pytest.mark.parametrize(
    ("changes", "expected"),
    [
        (  # a cycle through a function-level import and one under TYPE_CHECKING
            {"fake/late.py": "import typing\nif typing.TYPE_CHECKING:\n    import fake.core\n"},
            ["import cycle of 2 modules: fake.core, fake.late"],
        ),
        (  # a longer one, through relative imports
            {
                "fake/errors.py": "def f():\n    from .late import x\n",
                "fake/late.py": "from .util.maths import helper\n",
            },
            ["import cycle of 3 modules: fake.errors, fake.late, fake.util.maths"],
        ),
        (  # two separate cycles, each listed
            {
                "fake/late.py": "from fake.core import run\n",
                "fake/util/maths.py": "from fake.util import helper\n",
            },
            [
                "import cycle of 2 modules: fake.core, fake.late",
                "import cycle of 2 modules: fake.util, fake.util.maths",
            ],
        ),
        (
            {"fake/errors.py": "import fake.errors\n"},
            ["fake.errors imports itself"],
        ),
    ],
)
def test_cycle_finder_finds_cycles(tmp_path: Path, changes, expected) -> None:
    _write_package(tmp_path, {**CLEAN, **changes})
    assert cycle_report(import_graph(tmp_path, "fake")) == expected


def test_upward_imports_are_found(tmp_path: Path) -> None:
    _write_package(
        tmp_path,
        {
            **CLEAN,
            "fake/late.py": "def f():\n    from fake.viz import run\n",
            "fake/util/maths.py": "from ..pipeline import stage\n",
            "fake/pipeline.py": "import fake.viz\nstage = 1\n",
        },
    )
    assert upward_imports(import_graph(tmp_path, "fake"), "fake") == [
        "fake.late -> fake.viz",
        "fake.util.maths -> fake.pipeline",
    ]


# Among the top packages, each imports only those before it here: the frame loop is shared by
# the commands and the site service, the nodes feed the site service, the control room reuses
# the site's wire format and console files, and the commands are above everything they run.
TOP_ORDER = ("pipeline", "nodes", "site", "controlroom", "cli")


def test_the_top_packages_import_down_their_order() -> None:
    graph = import_graph()
    rank = {f"{PACKAGE}.{t}": i for i, t in enumerate(TOP_ORDER)}

    def rank_of(module: str) -> int | None:
        return next((r for p, r in rank.items() if _within(module, p)), None)

    upward = []
    for m in sorted(graph):
        for t in sorted(graph[m]):
            a, b = rank_of(m), rank_of(t)
            if a is not None and b is not None and b > a:
                upward.append(f"{m} -> {t}")
    assert not upward, "\n".join(upward)


def test_the_http_kit_knows_no_site_and_no_control_room() -> None:
    """stereopose.web (the server, hosts, limits, error answers, users, sessions, logins) is
    shared by the site and the control room: it imports neither, nor anything above them."""
    graph = import_graph()
    above = [f"{PACKAGE}.{t}" for t in TOP]
    found = [
        f"{m} -> {t}"
        for m in sorted(graph)
        if _within(m, f"{PACKAGE}.web")
        for t in sorted(graph[m])
        if any(_within(t, a) for a in above)
    ]
    assert not found, "\n".join(found)
    uses = {m for m in graph if any(_within(t, f"{PACKAGE}.web") for t in graph[m])}
    assert any(_within(m, f"{PACKAGE}.site") for m in uses)
    assert any(_within(m, f"{PACKAGE}.controlroom") for m in uses)


# -- the layers' rules -------------------------------------------------------------------------

# what the zones (low in the stack: fences, behaviour, tickets and zone state use them) may use
ZONES_USE = ("alarms.priority", "alarms.levels", "checks", "errors", "secrets", "skeleton", "types")
# network clients belong where their protocols live (scada/, io/), never among the fences or zones
NETWORK = (
    "c104",
    "asyncua",
    "paho",
    "socket",
    "http",
    "urllib",
    "requests",
    "aiohttp",
    "websockets",
)


def package_of(module: str, package: str = PACKAGE) -> str:
    """``stereopose.a.b`` -> ``a``; the package itself is itself."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 and parts[0] == package else module


def mutual_packages(graph: Mapping[str, Iterable[str]], package: str = PACKAGE) -> list[str]:
    """``a <-> b`` for each pair of sub-packages that import each other (through any modules)."""
    edges = {
        (package_of(m, package), package_of(t, package))
        for m, targets in graph.items()
        for t in targets
    }
    return sorted(f"{a} <-> {b}" for a, b in edges if a < b and (b, a) in edges)


def outside_imports(package: str, sub: str) -> set[str]:
    """Every top-level name that the modules of ``package.sub`` import from outside ``package``."""
    found = set()
    for path in (SRC / package / sub).rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Import):
                found.update(a.name.split(".")[0] for a in node.names)
            elif isinstance(node, ast.ImportFrom) and not node.level and node.module:
                found.add(node.module.split(".")[0])
    return found - {package}


def test_no_two_packages_import_each_other() -> None:
    mutual = mutual_packages(import_graph())
    assert not mutual, "packages that import each other:\n" + "\n".join(mutual)


def test_mutual_packages_are_found() -> None:
    graph = {"p.a.x": {"p.b.y"}, "p.b.y": set(), "p.b.z": {"p.a"}, "p.c": {"p.a.x"}}
    assert mutual_packages(graph, "p") == ["a <-> b"]


def test_the_zones_import_nothing_above_them() -> None:
    allowed = tuple(f"{PACKAGE}.{m}" for m in (*ZONES_USE, "zones"))
    above = sorted(
        f"{m} -> {t}"
        for m, targets in import_graph().items()
        if _within(m, f"{PACKAGE}.zones")
        for t in targets
        if not any(_within(t, a) for a in allowed)
    )
    assert not above, "the zones import from above them:\n" + "\n".join(above)


@pytest.mark.parametrize("sub", ["fence", "zones", "behaviour", "tickets"])
def test_no_network_client_among_the_fences_zones_behaviour_and_tickets(sub: str) -> None:
    clients = sorted(outside_imports(PACKAGE, sub) & set(NETWORK))
    assert not clients, f"{PACKAGE}/{sub} imports network clients: {clients}"
