"""Optional parts of the install: libraries a command needs beyond the runtime's base.

The runtime install (`pip install stereopose`, what `serve` needs) leaves out the libraries of
the offline tools: the HTML report (plotly) and the calibration solver and pictures (scipy,
matplotlib). A command that needs one checks for it before it starts its work, so a runtime
install answers with an error naming the extra to install rather than an ImportError.
"""

from __future__ import annotations

import importlib.util

from stereopose.errors import StereoposeError

__all__ = ["MissingExtraError", "require"]


class MissingExtraError(StereoposeError):
    """A library of an optional extra is not installed."""


def _installed(module: str) -> bool:
    try:
        return importlib.util.find_spec(module) is not None
    except (ImportError, ValueError):  # a broken or half-removed install
        return False


def require(module: str, extra: str, purpose: str, hint: str = "") -> None:
    """Raise MissingExtraError unless ``module`` can be imported.

    extra: the name of the pyproject extra that installs it; purpose: what needs it, as the
    start of a sentence ("the HTML report"); hint: another way out, appended to the message.
    """
    if not _installed(module):
        raise MissingExtraError(
            f"{purpose} needs {module}, which this install does not have (a runtime install "
            f"leaves it out): pip install 'stereopose[{extra}]'" + (f"; {hint}" if hint else "")
        )
