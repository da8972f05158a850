"""Errors raised on bad input; each message names the file or object and the problem."""

from __future__ import annotations


class StereoposeError(Exception):
    """Base of every error stereopose raises on bad input or configuration."""


class CalibrationError(StereoposeError, ValueError):
    """A calibration file or camera is malformed."""


class KeypointsError(StereoposeError, ValueError):
    """2D keypoint input is malformed or missing."""


class ConfigError(StereoposeError, ValueError):
    """A configuration file or value is invalid."""


class OutputError(StereoposeError):
    """An output cannot be written (folder missing or read-only, disk full, database locked).

    Raised before the work starts it is bad configuration (exit code 2); once the work is under
    way, the output stops and the run goes on (see IncompleteOutputError).
    """


# The command line's exit codes (cli.main): done; bad input or configuration (a
# StereoposeError); finished, but some output could not be written; interrupted (Ctrl-C).
EXIT_OK = 0
EXIT_BAD_INPUT = 2
EXIT_OUTPUT_FAILED = 3
EXIT_INTERRUPTED = 130


class IncompleteOutputError(Exception):
    """The work finished, but some outputs could not be written (exit code 3).

    failures: output (a path or URL) -> why it could not be written; written: the outputs that
    were; summary: the run's summary, where there is one. Not a StereoposeError: the input was
    fine, and what could be written was.
    """

    exit_code = EXIT_OUTPUT_FAILED

    def __init__(
        self,
        failures: dict[str, str],
        written: list | None = None,
        summary: object | None = None,
        note: str = "",
    ) -> None:
        self.failures = dict(failures)
        self.written = list(written or [])
        self.summary = summary
        self.note = note
        n = len(self.failures)
        super().__init__(
            f"finished, but {n} output{'s' * (n != 1)} could not be written: "
            + "; ".join(f"{k}: {v}" for k, v in self.failures.items())
        )


class HashingBusyError(Exception):
    """Too many password checks under way: try again in a moment (nothing was checked)."""
