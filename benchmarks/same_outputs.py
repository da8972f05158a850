"""Whether two versions of stereopose write the same outputs, bit for bit: the real demo
(`stereopose demo`: poses3d.jsonl, events.jsonl, joints.csv, tracks.json, the event log's rows,
the ticket report) and the synthetic demo (`stereopose demo --synthetic`: every file).

    python benchmarks/same_outputs.py --base REV [--head REV] [--work DIR]

Each version (a git revision; --head defaults to the working tree) is checked out into DIR and
run with this project's .venv (its source tree first on the path); every output file is hashed
(SQLite event logs by their rows, in order, without the file's page layout and the `runs`
table's wall-clock start and end). Files that hold
wall-clock times or timings (the run's summary, the report pages, logs) are listed apart and not
compared. Writes results/same_outputs.{json,md}; exit 1 when a compared output differs.
"""

from __future__ import annotations

import argparse
import contextlib
import datetime
import hashlib
import json
import os
import sqlite3
import subprocess
import sys
from pathlib import Path

from common import RESULTS, machine

ROOT = Path(__file__).resolve().parents[1]
# outputs whose bytes hold the wall clock or how long things took: listed, never compared
TIMED = {"summary.json", "report.html", "config.toml", "stereopose.log"}
TIMED_SUFFIXES = (".log", ".png", ".mp4")
TIMED_TABLES = {"runs"}  # the event log's record of each run: its wall-clock start and end
DEMOS = {"real": ["demo"], "synthetic": ["demo", "--synthetic"]}


def _sqlite_digest(path: Path) -> str:
    """The rows of every table, in rowid order, hashed: the same log written twice is the same."""
    h = hashlib.sha256()
    with contextlib.closing(sqlite3.connect(f"file:{path}?mode=ro", uri=True)) as db:
        tables = [r[0] for r in db.execute("SELECT name FROM sqlite_master WHERE type='table'")]
        for table in sorted(set(tables) - TIMED_TABLES):
            h.update(table.encode())
            for row in db.execute(f'SELECT * FROM "{table}"'):
                h.update(repr(row).encode())
    return h.hexdigest()


def digests(folder: Path) -> dict[str, str]:
    """Relative path -> sha256 of every output file under `folder` (SQLite by its rows)."""
    out = {}
    for path in sorted(p for p in folder.rglob("*") if p.is_file()):
        rel = str(path.relative_to(folder))
        if path.name.endswith(("-wal", "-shm", "-journal")):
            continue
        if path.suffix in (".sqlite", ".db"):
            out[rel] = "rows:" + _sqlite_digest(path)
        else:
            out[rel] = hashlib.sha256(path.read_bytes()).hexdigest()
    return out


def timed(rel: str) -> bool:
    name = Path(rel).name
    return name in TIMED or name.endswith(TIMED_SUFFIXES)


def checkout(rev: str | None, work: Path) -> Path:
    """The source tree of `rev` (None: this working tree)."""
    if rev is None:
        return ROOT
    tree = work / f"tree-{rev}"
    if not tree.exists():
        add = ["git", "-C", str(ROOT), "worktree", "add", "-f", str(tree), rev]
        subprocess.run(add, check=True)
    return tree


def run_demos(tree: Path, out: Path) -> dict[str, dict[str, str]]:
    env = {**os.environ, "PYTHONPATH": str(tree / "src")}
    python = str(ROOT / ".venv" / "bin" / "python")
    found = {}
    for name, args in DEMOS.items():
        folder = out / name
        cmd = [python, "-m", "stereopose.cli", *args, "--out", str(folder), "--overwrite"]
        subprocess.run(cmd, check=True, env=env, cwd=tree, stdout=subprocess.DEVNULL)
        found[name] = digests(folder)
    return found


def compare(base: dict, head: dict) -> tuple[list[str], list[str], list[str]]:
    """(same, different, not compared) relative paths, `demo/file`."""
    same, different, skipped = [], [], []
    for demo in DEMOS:
        for rel in sorted(set(base[demo]) | set(head[demo])):
            key = f"{demo}/{rel}"
            if timed(rel):
                skipped.append(key)
            elif base[demo].get(rel) == head[demo].get(rel):
                same.append(key)
            else:
                different.append(key)
    return same, different, skipped


def _digest(found: dict, key: str) -> str:
    demo, rel = key.split("/", 1)
    return found[demo][rel]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--base", required=True, help="the git revision to compare against")
    ap.add_argument("--head", default=None, help="the other revision (default: the working tree)")
    ap.add_argument("--work", type=Path, default=ROOT / "out" / "same-outputs")
    args = ap.parse_args()
    args.work.mkdir(parents=True, exist_ok=True)
    found = {}
    for label, rev in (("base", args.base), ("head", args.head)):
        tree = checkout(rev, args.work)
        found[label] = run_demos(tree, args.work / label)
        print(f"{label} ({rev or 'working tree'}): {sum(map(len, found[label].values()))} files")
    same, different, skipped = compare(found["base"], found["head"])
    head_rev = (
        args.head
        or subprocess.run(
            ["git", "-C", str(ROOT), "describe", "--always", "--dirty"],
            capture_output=True,
            text=True,
        ).stdout.strip()
    )
    result = {
        "date": datetime.date.today().isoformat(),
        "machine": machine().replace(", one thread", ""),
        "base": args.base,
        "head": head_rev,
        "same": same,
        "different": different,
        "not_compared": skipped,
        "digests": found["head"],
    }
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "same_outputs.json").write_text(json.dumps(result, indent=1) + "\n")
    lines = [
        "# The same outputs, bit for bit",
        "",
        f"{result['date']}, {result['machine']}: `{args.base}` against `{head_rev}`, "
        "`python benchmarks/same_outputs.py`.",
        "",
        f"- **identical**: {len(same)} files",
        f"- **different**: {len(different)} files {', '.join(different)}".rstrip(),
        f"- not compared (wall-clock times, timings, pictures): {', '.join(skipped) or 'none'}",
        "",
        "| file | sha256 (head) |",
        "|---|---|",
        *(f"| {k} | `{_digest(found['head'], k)[:16]}` |" for k in same),
    ]
    (RESULTS / "same_outputs.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines[:7]))
    return 1 if different else 0


if __name__ == "__main__":
    sys.exit(main())
