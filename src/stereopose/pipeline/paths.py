"""Where a command reads and where it writes, checked before anything is written.

Every command that writes (reconstruct, run, detect, calibrate, demo) names its inputs and its
outputs as `Place`s. `check_places` refuses an output that is an input (the same path, a
symbolic or hard link to it, a spelling with `..`), an output inside an input folder (it would
be read as input the next time), and two outputs at one path. `claim_folder` makes a folder
hold one run: what a previous run wrote there is refused, or with `overwrite` removed first;
no other file in the folder is touched.
"""

from __future__ import annotations

import fnmatch
import json
import logging
import os
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

from stereopose.errors import ConfigError, OutputError
from stereopose.pipeline.outputs import Outputs

logger = logging.getLogger(__name__)

# what a run writes in its folder, whatever its configuration (see pipeline.run)
RUN_FILES = (
    "poses3d.jsonl",
    "events.jsonl",
    "events.sqlite",
    "joints.csv",
    "tracks.json",
    "report.html",
    "summary.json",
    "config.toml",
    "calib.toml",
    "site.toml",
)
SQLITE_SIDECARS = ("-wal", "-shm", "-journal")
RUN_PATTERNS = ("trc/person_*.trc", "overlays/*.mp4")
TRC_PATTERNS = ("person_*.trc",)


@dataclass(frozen=True)
class Place:
    """A path a command reads or writes; `what` is how the user named it (an option such as
    "--calib", a configuration key such as "calibration").

    reads (an input folder): globs, relative to it, of what is read there as input; an output
    matching one, or any output folder inside it, is refused. folder (an output): it is a
    folder of outputs (a new folder inside an input folder may be read as one of its own).
    """

    what: str
    path: Path
    reads: tuple[str, ...] = ("*",)
    folder: bool = False


# a keypoints folder reads *.json files in its camera folders (and sub-folders as cameras): a
# file beside the camera folders that is not .json is never read
POSE_READS = ("*/*", "*.json")


def places(*pairs: tuple[str, str | Path | None]) -> list[Place]:
    """Places of (what, path) pairs; a None path (not given) is left out."""
    return [Place(what, Path(path)) for what, path in pairs if path is not None]


def sqlite_places(what: str, path: Path) -> list[Place]:
    """An SQLite file and the journal files SQLite writes beside it."""
    return [Place(what, path)] + [
        Place(f"{what} (its {s[1:]} file)", path.with_name(path.name + s)) for s in SQLITE_SIDECARS
    ]


def _resolved(path: Path) -> str:
    # strict=False: an output that does not exist yet is its resolved parent plus its name
    return os.path.normcase(str(Path(os.path.expanduser(path)).resolve(strict=False)))


def same_path(a: Path, b: Path) -> bool:
    """Whether `a` and `b` name one file or folder: the same inode where both exist (links
    included), else the same resolved path."""
    try:
        return os.path.samefile(a, b)
    except OSError:
        return _resolved(a) == _resolved(b)


def _inside(path: Path, folder: Path) -> bool:
    return Path(_resolved(path)).is_relative_to(_resolved(folder))


def _read_as_input(output: Place, folder: Place) -> bool:
    """Whether `output`, inside the input folder `folder`, would be read as input."""
    if output.folder:
        return True
    rel = Path(_resolved(output.path)).relative_to(_resolved(folder.path)).as_posix().lower()
    return any(fnmatch.fnmatchcase(rel, pattern) for pattern in folder.reads)


def _files_under(folder: Path) -> Iterator[Path]:
    for root, _, names in os.walk(folder):
        for name in names:
            yield Path(root, name)


def _hard_link_into(output: Path, folders: Sequence[Place]) -> Place | None:
    """The input folder holding another name of `output` (a hard link), if any. Folders are
    walked only for an existing file with more than one name, which is rare."""
    try:
        st = output.stat()
    except OSError:
        return None
    if st.st_nlink < 2 or not output.is_file():
        return None
    for folder in folders:
        for f in _files_under(folder.path):
            try:
                if os.path.samefile(f, output):
                    return Place(f"{folder.what} file", f)
            except OSError:
                continue
    return None


def _refuse(output: Place, why: str, hint: str) -> ConfigError:
    return ConfigError(f"refusing to write {output.what} {output.path}: {why}; {hint}")


def _check_output(
    output: Place, inputs: Sequence[Place], folders: Sequence[Place], hint: str
) -> None:
    for i in inputs:
        if same_path(output.path, i.path):
            raise _refuse(output, f"it is the {i.what} {i.path}, an input", hint)
    for f in folders:
        if _inside(output.path, f.path) and _read_as_input(output, f):
            why = f"it lies inside the {f.what} folder {f.path}, which is read as input"
            raise _refuse(output, why, hint)
    linked = _hard_link_into(output.path, folders)
    if linked is not None:
        raise _refuse(output, f"it is a hard link to the {linked.what} {linked.path}", hint)


def check_places(
    inputs: Iterable[Place], outputs: Iterable[Place], hint: str = "choose another path"
) -> None:
    """ConfigError naming both paths if an output is an input, lies inside an input folder,
    or is the path of another output; `hint` says what to do. Nothing is written: checked
    before anything is."""
    inputs, outputs = list(inputs), list(outputs)
    folders = [i for i in inputs if i.path.is_dir()]
    for k, o in enumerate(outputs):
        _check_output(o, inputs, folders, hint)
        for other in outputs[:k]:
            if same_path(o.path, other.path):
                why = f"{other.what} writes the same path {other.path}"
                raise _refuse(o, why, "give each output its own path")
        for other in outputs:  # a file in a folder another output fills (--trc) may collide
            if other.folder and not o.folder and _inside(o.path, other.path):
                why = (
                    f"it lies inside the {other.what} folder {other.path}, which that output fills"
                )
                raise _refuse(o, why, "give each output its own path")


def _listed_outputs(folder: Path) -> list[Path]:
    """The outputs a previous run's summary.json lists inside `folder` (its manifest)."""
    try:
        listed = json.loads((folder / "summary.json").read_text(encoding="utf-8"))["outputs"]
        paths = [Path(p) for p in listed if isinstance(p, str)]
    except (OSError, ValueError, KeyError, TypeError):
        return []
    return [p for p in paths if p.is_file() and _inside(p, folder)]


def run_products(folder: Path) -> list[Path]:
    """The files in a run folder that a run writes: the known names, the TRC and overlay
    files, and whatever the folder's summary.json lists as written there."""
    names = [*RUN_FILES, *(f"events.sqlite{s}" for s in SQLITE_SIDECARS)]
    found = [folder / n for n in names if (folder / n).is_file()]
    found += pattern_products(RUN_PATTERNS)(folder)
    return sorted(set(found) | set(_listed_outputs(folder)))


def pattern_products(patterns: Sequence[str]) -> Callable[[Path], list[Path]]:
    """The files matching `patterns` (globs relative to the folder)."""

    def found(folder: Path) -> list[Path]:
        return sorted({p for pat in patterns for p in folder.glob(pat) if p.is_file()})

    return found


def previous_outputs(
    folder: Place,
    products: Callable[[Path], list[Path]],
    overwrite: bool,
    inputs: Sequence[Place] = (),
) -> list[Path]:
    """What a previous run left in `folder` that this one would write beside or over
    (`products(folder)`: the files a run of this kind writes there; never an input). Mixing
    the two runs' results is refused: a ConfigError without `overwrite`; with it, the files
    to remove (`remove_outputs`) just before this run writes."""
    if not folder.path.is_dir():
        return []
    check_writable(folder)
    previous = [p for p in products(folder.path) if not any(same_path(p, i.path) for i in inputs)]
    if previous and not overwrite:
        shown = ", ".join(str(p.relative_to(folder.path)) for p in previous[:4])
        more = f" and {len(previous) - 4} more" if len(previous) > 4 else ""
        raise ConfigError(
            f"{folder.what} {folder.path} already holds a previous run's outputs ({shown}{more}): "
            "pass --overwrite to replace them, or choose another folder"
        )
    return previous


def check_writable(folder: Place) -> None:
    """An OutputError naming `folder` and the reason when nothing can be written in it (a
    read-only file system, no permission): refused before any work, not half-way."""
    # access() answers EROFS for a read-only mount even to root, and touches nothing
    if not os.access(folder.path, os.W_OK | os.X_OK):
        why = "read-only file system" if _read_only(folder.path) else "permission denied"
        raise OutputError(f"{folder.what} {folder.path}: cannot write there ({why})")


def _read_only(path: Path) -> bool:
    try:
        return bool(os.statvfs(path).f_flag & os.ST_RDONLY)
    except OSError:
        return False


def remove_outputs(paths: Sequence[Path]) -> None:
    """Remove a previous run's outputs (from `previous_outputs`)."""
    for p in paths:
        try:
            p.unlink()
        except FileNotFoundError:
            continue
        except OSError as e:
            raise ConfigError(
                f"{p}: cannot remove the previous run's output ({e.strerror}); nothing written"
            ) from None
    if paths:
        logger.info("removed %d outputs of a previous run", len(paths))


# how reconstruct's options name each field of pipeline.outputs.Outputs
FLAGS = {
    "poses": "--out",
    "events": "--events",
    "events_db": "--events-db",
    "trc_dir": "--trc",
    "csv": "--csv",
    "tracks": "--tracks",
}


def output_places(outputs: Outputs, what: Callable[[str, Path], str]) -> list[Place]:
    """Every path `outputs` writes (pipeline.outputs.Outputs): files, the TRC and overlay
    folders, the SQLite log's journals, report.html; what(field, path) names each."""
    found: list[Place] = []
    for field, path in (
        ("poses", outputs.poses),
        ("events", outputs.events),
        ("csv", outputs.csv),
        ("tracks", outputs.tracks),
        ("summary", outputs.summary),
        ("trc_dir", outputs.trc_dir),
        ("overlays_dir", outputs.overlays_dir),
    ):
        if path is not None:
            found.append(Place(what(field, path), Path(path), folder=field.endswith("_dir")))
    if outputs.events_db is not None:
        found += sqlite_places(what("events_db", outputs.events_db), Path(outputs.events_db))
    if outputs.report_dir is not None:
        report = Path(outputs.report_dir) / "report.html"
        found.append(Place(what("report", report), report))
    return found


def flag(field: str, path: Path) -> str:
    """reconstruct's option for an output field."""
    return FLAGS.get(field, f"output {Path(path).name}")


def in_run_folder(field: str, path: Path) -> str:
    """A run folder's output, named by its file name."""
    return f"{Path(path).name} in the output folder"


def check_calibration_places(
    images: Path,
    out: Path,
    report_dir: Path | None,
    report_name: str,
    intrinsics: Path | None = None,
    intrinsics_images: Path | None = None,
) -> None:
    """calibrate's checks: --out (a .toml, or the intri.yml and extri.yml of a folder or .yml)
    and the report picture never an input (--images, --intrinsics, --intrinsics-images), nor
    inside an input folder (it would be read as photos or a camera's folder)."""
    inputs = places(("--images", images), ("--intrinsics-images", intrinsics_images))
    inputs += _calibration_files("--intrinsics", intrinsics)
    outputs = _calibration_files("--out", out, written=True)
    if report_dir is not None:
        outputs += places(("--report", Path(report_dir) / report_name))
    check_places(inputs, outputs)


def _calibration_files(what: str, path: Path | None, written: bool = False) -> list[Place]:
    """A calibration path as the files it stands for: a .toml itself; otherwise (a folder, a
    .yml) the OpenCV YAML pair intri.yml / extri.yml of its folder, as they are written and
    read; an input is also itself (a .qca.txt, a folder)."""
    if path is None:
        return []
    path = Path(path)
    found = [] if written else [Place(what, path)]
    if path.suffix.lower() == ".toml":
        return [Place(what, path)]
    if written or path.is_dir() or path.suffix.lower() in (".yml", ".yaml"):
        folder = path.parent if path.suffix.lower() in (".yml", ".yaml") else path
        found += [Place(f"{what} {name}", folder / name) for name in ("intri.yml", "extri.yml")]
    return found
