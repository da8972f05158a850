"""Pictures: calibration reports (and, later, overlays and the run report)."""
