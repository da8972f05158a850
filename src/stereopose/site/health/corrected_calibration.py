"""The corrected calibration a restart loads: the newest `<name>.corrected.toml` the
calibration keeper (site.health.calib_keeper) wrote for a calibration file."""

from __future__ import annotations

import logging
import tomllib
from collections.abc import Sequence
from pathlib import Path

logger = logging.getLogger(__name__)


def corrected_file(calib_path: str | Path, places: Sequence[str | Path] = ()) -> Path | None:
    """The newest `<name>.corrected.toml` the keeper wrote for the calibration at `calib_path`
    (beside it, or in one of `places`), when it is newer than the original: a restart keeps the
    correction; an original changed since (calibrated again) wins. A corrected file that cannot
    be read, or was corrected from another file, is skipped with a log line."""
    calib_path = Path(calib_path)
    stem = calib_path.name.split(".")[0] or "calibration"
    try:
        since = calib_path.stat().st_mtime
    except OSError:
        return None
    found: list[tuple[float, Path]] = []
    for folder in [calib_path.parent, *map(Path, places)]:
        path = folder / f"{stem}.corrected.toml"
        try:
            mtime = path.stat().st_mtime
            with open(path, "rb") as f:
                meta = tomllib.load(f).get("metadata", {})
        except FileNotFoundError:
            continue
        except (OSError, tomllib.TOMLDecodeError) as e:
            logger.error("%s: the corrected calibration is not used: %s", path, e)
            continue
        source = meta.get("corrected_from") if isinstance(meta, dict) else None
        if source is None or Path(str(source)).resolve() != calib_path.resolve():
            logger.warning("%s: not corrected from %s: not used", path, calib_path)
        elif mtime < since:
            logger.warning(
                "%s is older than %s (calibrated again since): not used", path, calib_path
            )
        else:
            found.append((mtime, path))
    return max(found)[1] if found else None
