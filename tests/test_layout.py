"""The code's shape: no function of the package longer than MAX_FUNCTION_LINES lines, no
module longer than MAX_MODULE_LINES."""

from __future__ import annotations

import ast
from pathlib import Path

SRC = Path(__file__).resolve().parents[1] / "src" / "stereopose"
MAX_FUNCTION_LINES = 100
MAX_MODULE_LINES = 500


def long_functions(root: Path = SRC, limit: int = MAX_FUNCTION_LINES) -> list[str]:
    """`path:line name (n lines)` of each function or method longer than `limit` lines."""
    found = []
    for path in sorted(root.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                n = node.end_lineno - node.lineno + 1
                if n > limit:
                    found.append(f"{path.relative_to(root)}:{node.lineno} {node.name} ({n} lines)")
    return found


def test_no_function_is_over_the_limit() -> None:
    found = long_functions()
    assert not found, "functions over the limit:\n" + "\n".join(found)


def test_a_long_function_is_found(tmp_path: Path) -> None:
    body = "\n".join(f"    x{k} = {k}" for k in range(MAX_FUNCTION_LINES))
    (tmp_path / "long.py").write_text(f"def long():\n{body}\n\n\ndef short():\n    pass\n")
    assert long_functions(tmp_path) == [f"long.py:1 long ({MAX_FUNCTION_LINES + 1} lines)"]


def long_modules(root: Path = SRC, limit: int = MAX_MODULE_LINES) -> list[str]:
    """`path (n lines)` of each module longer than `limit` lines."""
    found = []
    for path in sorted(root.rglob("*.py")):
        n = len(path.read_text(encoding="utf-8").splitlines())
        if n > limit:
            found.append(f"{path.relative_to(root)} ({n} lines)")
    return found


def test_no_module_is_over_the_limit() -> None:
    found = long_modules()
    assert not found, "modules over the limit:\n" + "\n".join(found)


def test_a_long_module_is_found(tmp_path: Path) -> None:
    (tmp_path / "short.py").write_text("x = 1\n" * MAX_MODULE_LINES)
    (tmp_path / "long.py").write_text("x = 1\n" * (MAX_MODULE_LINES + 1))
    assert long_modules(tmp_path) == [f"long.py ({MAX_MODULE_LINES + 1} lines)"]
