"""What the benchmark scripts share: the machine's description, the scene arguments, one core,
and writing results/<name>.{json,md}."""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
from pathlib import Path

RESULTS = Path(__file__).resolve().parent / "results"


def machine() -> str:
    cpu = platform.processor() or "unknown CPU"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return f"{cpu}, {os.cpu_count()} cores, Python {platform.python_version()}, one thread"


def start(doc: str) -> tuple[argparse.Namespace, dict]:
    """Parse --frames and --seeds, keep the process on one core, and begin the results with
    the date, the machine and the arguments."""
    ap = argparse.ArgumentParser(description=doc.splitlines()[0])
    ap.add_argument("--frames", type=int, default=300)
    ap.add_argument("--seeds", type=int, default=5)
    args = ap.parse_args()
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
    head = {
        "date": datetime.date.today().isoformat(),
        "machine": machine(),
        "frames": args.frames,
        "seeds": args.seeds,
    }
    return args, head


def save(name: str, results: dict, md: list[str]) -> Path:
    """Write results/<name>.json and results/<name>.md; returns the latter."""
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / f"{name}.json").write_text(json.dumps(results, indent=2) + "\n")
    path = RESULTS / f"{name}.md"
    path.write_text("\n".join(md) + "\n")
    print(f"written {path}")
    return path
