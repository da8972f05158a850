"""The site service's health: its state, the camera watch, stalls, calibration drift, metrics,
rates, the alarm outputs' health and the watchdog."""
