"""The code's shape: no function of the package longer than MAX_FUNCTION_LINES lines, no
module longer than MAX_MODULE_LINES; few attributes read by name, few `Any`, few long
parameter lists."""

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


# Names looked up as strings and untyped values, kept few: an attribute is read by name only
# where the name is data (a dataclass's fields, a third party's optional attribute), `Any` only
# where a value truly is anything; a long parameter list becomes a settings dataclass (the
# compiled numba kernels, which take arrays only, and a few public entry points keep theirs).
MAX_GETATTR = 50
MAX_ANY = 60
MANY_PARAMETERS = 9
MAX_MANY_PARAMETERS = 12


def getattr_calls(root: Path = SRC) -> int:
    """Calls of getattr() in the package's code."""
    return sum(
        isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == "getattr"
        for path in sorted(root.rglob("*.py"))
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8")))
    )


def any_uses(root: Path = SRC) -> int:
    """Uses of typing.Any as a name in the package's code (its imports not counted)."""
    return sum(
        isinstance(node, ast.Name) and node.id == "Any"
        for path in sorted(root.rglob("*.py"))
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8")))
    )


def many_parameters(root: Path = SRC, many: int = MANY_PARAMETERS) -> list[str]:
    """`path:line name (n)` of each function taking `many` parameters or more (self and cls
    not counted; *args and **kwargs one each)."""
    found = []
    for path in sorted(root.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                a = node.args
                names = [*a.posonlyargs, *a.args, *a.kwonlyargs]
                n = len(names) + (a.vararg is not None) + (a.kwarg is not None)
                n -= bool(a.args) and a.args[0].arg in ("self", "cls")
                if n >= many:
                    found.append(f"{path.relative_to(root)}:{node.lineno} {node.name} ({n})")
    return found


def test_attributes_are_read_by_name_rarely() -> None:
    n = getattr_calls()
    assert n <= MAX_GETATTR, f"{n} getattr() calls, at most {MAX_GETATTR}"


def test_any_is_rare() -> None:
    n = any_uses()
    assert n <= MAX_ANY, f"{n} uses of Any, at most {MAX_ANY}"


def test_few_functions_take_many_parameters() -> None:
    found = many_parameters()
    assert len(found) <= MAX_MANY_PARAMETERS, (
        f"{len(found)} functions take {MANY_PARAMETERS} parameters or more, at most "
        f"{MAX_MANY_PARAMETERS}:\n" + "\n".join(found)
    )


def test_the_counters_find_what_they_count(tmp_path: Path) -> None:
    (tmp_path / "m.py").write_text(
        "from typing import Any\n\n"
        "class C:\n"
        "    def m(self, a, b, c, d, e, f, g, h, i: Any) -> Any:\n"
        "        return getattr(a, 'x', getattr(b, 'y', None))\n\n"
        "def short(a, b, *rest, **kw):\n"
        "    return a\n"
    )
    assert getattr_calls(tmp_path) == 2
    assert any_uses(tmp_path) == 2
    assert many_parameters(tmp_path) == ["m.py:4 m (9)"]
