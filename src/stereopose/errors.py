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
