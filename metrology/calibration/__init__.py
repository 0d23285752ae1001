"""metro.calibration."""
