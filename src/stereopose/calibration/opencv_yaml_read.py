"""A reader of the YAML that cv2.FileStorage writes, in plain Python, safe on any input.

cv2.FileStorage itself raises SystemError, or corrupts memory and aborts the process, on some
malformed files, so calibration files are parsed here instead. The subset is what OpenCV and
EasyMocap write: a top-level mapping of keys to plain or quoted scalars, flow lists
(``[ 1., 2. ]``, over several lines), block lists (``- cam01``) and ``!!opencv-matrix`` blocks
(``rows``, ``cols``, ``dt``, ``data``). Anything else is a CalibrationError naming the file and
the line.
"""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

from stereopose.checks import read_limited
from stereopose.errors import CalibrationError

Node = str | list["Node"] | dict[str, "Node"]  # scalars stay text until read as numbers
_KEY = re.compile(r"^(.+?):(?:\s+|$)(.*)$")
_SPECIAL = {".nan": math.nan, ".inf": math.inf, "+.inf": math.inf, "-.inf": -math.inf}
_TAGS = ("!!opencv-matrix", "!<tag:yaml.org,2002:opencv-matrix>")
_Line = tuple[int, str, int]  # indentation, text, line number


def read_yaml(path: Path) -> dict[str, Node]:
    """The top-level mapping of an OpenCV YAML file."""
    raw = read_limited(path, "calibration file", CalibrationError)
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as e:
        raise CalibrationError(f"{path}: not UTF-8 text (byte {e.start}); expected YAML") from None
    return parse_yaml(text, path)


def number(node: Node, where: str) -> float:
    """A scalar read as a float (YAML's .nan and .inf included; the caller checks ranges)."""
    if isinstance(node, str):
        t = node.strip().lower()
        if t in _SPECIAL:
            return _SPECIAL[t]
        try:
            return float(t)
        except ValueError:
            pass
    shown = repr(node) if len(repr(node)) <= 60 else repr(node)[:57] + "..."
    raise CalibrationError(f"{where}: expected a number, got {shown}")


def parse_yaml(text: str, path: Path | str) -> dict[str, Node]:
    """The top-level mapping of OpenCV YAML text; errors name `path` and the line."""
    lines = _lines(text, path)
    doc: dict[str, Node] = {}
    i = 0
    while i < len(lines):
        indent, content, no = lines[i]
        if indent:
            raise CalibrationError(f"{path}: line {no}: unexpected indentation")
        key, rest = _split_key(content, path, no)
        rest = _strip_tag(rest, path, no)
        if rest:
            value, i = _inline(rest, lines, i, path)
        else:
            j = i + 1
            while j < len(lines) and lines[j][0] > 0:
                j += 1
            if j == i + 1:
                raise CalibrationError(f"{path}: line {no}: `{key}` has no value")
            value, i = _block(lines[i + 1 : j], path), j
        if key in doc:
            raise CalibrationError(f"{path}: line {no}: `{key}` appears twice")
        doc[key] = value
    return doc


def _lines(text: str, path: Path | str) -> list[_Line]:
    out = []
    for no, raw in enumerate(text.splitlines(), start=1):
        line = _uncomment(raw).rstrip()
        stripped = line.lstrip(" ")
        if not stripped or (line.startswith("%") or stripped in ("---", "...")):
            continue  # directives (%YAML:1.0) and document markers
        if stripped.startswith("\t"):
            raise CalibrationError(f"{path}: line {no}: tabs cannot indent YAML")
        out.append((len(line) - len(stripped), stripped, no))
    return out


def _uncomment(line: str) -> str:
    """The line without a trailing `# comment` (a # outside quotes, after a space or first)."""
    quote = ""
    for k, c in enumerate(line):
        if quote:
            if c == quote:
                quote = ""
        elif c in "\"'":
            quote = c
        elif c == "#" and (k == 0 or line[k - 1] in " \t"):
            return line[:k]
    return line


def _split_key(content: str, path: Path | str, no: int) -> tuple[str, str]:
    m = _KEY.match(content)
    if m is None or content.startswith(("-", "[", "{")):
        raise CalibrationError(f"{path}: line {no}: expected `key: value`, got {content[:60]!r}")
    return _scalar(m.group(1), path, no), m.group(2).strip()


def _strip_tag(rest: str, path: Path | str, no: int) -> str:
    if not rest.startswith("!"):
        return rest
    tag, _, after = rest.partition(" ")
    if tag not in _TAGS:
        raise CalibrationError(f"{path}: line {no}: unsupported tag {tag[:40]!r}")
    return after.strip()


def _inline(rest: str, lines: list[_Line], i: int, path: Path | str) -> tuple[Node, int]:
    """The value written after `key:` (a flow list may go on over the next lines) and the index
    of the line after it."""
    no = lines[i][2]
    if not rest.startswith("["):
        return _scalar(rest, path, no), i + 1
    text = rest
    while _depth(text, path, no) > 0:
        i += 1
        if i == len(lines):
            raise CalibrationError(f"{path}: line {no}: `[` is never closed")
        text += " " + lines[i][1]
    return _flow_list(text, path, no), i + 1


def _depth(text: str, path: Path | str, no: int) -> int:
    """Brackets still open at the end of text (outside quotes); nesting is not supported."""
    depth, quote = 0, ""
    for c in text:
        if quote:
            quote = "" if c == quote else quote
        elif c in "\"'":
            quote = c
        elif c in "[{":
            depth += 1
            if depth > 1 or c == "{":
                raise CalibrationError(f"{path}: line {no}: nested lists or maps not supported")
        elif c in "]}":
            depth -= 1
            if depth < 0:
                raise CalibrationError(f"{path}: line {no}: unbalanced `]`")
    return depth


def _flow_list(text: str, path: Path | str, no: int) -> list[Node]:
    text = text.strip()
    if not text.endswith("]"):
        raise CalibrationError(f"{path}: line {no}: text after the closing `]`")
    inner = text[1:-1].strip()
    if not inner:
        return []
    items = re.findall(r"\"(?:[^\"\\]|\\.)*\"|'(?:[^']|'')*'|[^,]+|,", inner)
    values, expect_item = [], True
    for item in items:
        if item == ",":
            if expect_item:
                raise CalibrationError(f"{path}: line {no}: empty item in a list")
            expect_item = True
        elif item.strip():
            if not expect_item:
                raise CalibrationError(f"{path}: line {no}: `,` missing between list items")
            values.append(_scalar(item, path, no))
            expect_item = False
    return values


def _block(block: list[_Line], path: Path | str) -> Node:
    """An indented block: a list of `- item` lines or a mapping of `key: value` lines."""
    base = block[0][0]
    if block[0][1].startswith("-") and block[0][1][1:2] in ("", " "):
        items: list[Node] = []
        for indent, content, no in block:
            if indent != base or not (content == "-" or content.startswith("- ")):
                raise CalibrationError(f"{path}: line {no}: expected `- item` in the list")
            items.append(_scalar(content[1:], path, no))
        return items
    mapping: dict[str, Node] = {}
    i = 0
    while i < len(block):
        indent, content, no = block[i]
        if indent != base:
            raise CalibrationError(f"{path}: line {no}: nested blocks are not supported")
        key, rest = _split_key(content, path, no)
        if not rest:
            raise CalibrationError(f"{path}: line {no}: `{key}` has no value")
        if key in mapping:
            raise CalibrationError(f"{path}: line {no}: `{key}` appears twice")
        mapping[key], i = _inline(rest, block, i, path)
    return mapping


def _scalar(text: str, path: Path | str, no: int) -> str:
    t = text.strip()
    if t[:1] == '"':
        try:
            value = json.loads(t)  # YAML's double-quoted escapes, as far as OpenCV writes them
        except ValueError:
            value = None
        if not isinstance(value, str):
            raise CalibrationError(f"{path}: line {no}: bad double-quoted string {t[:60]!r}")
        return value
    if t[:1] == "'":
        if len(t) < 2 or not t.endswith("'"):
            raise CalibrationError(f"{path}: line {no}: bad single-quoted string {t[:60]!r}")
        return t[1:-1].replace("''", "'")
    if not t or t[0] in "&*!|>[]{}@`" or ": " in t:
        raise CalibrationError(f"{path}: line {no}: unsupported YAML value {t[:60]!r}")
    return t
