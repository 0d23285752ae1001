"""Tests of metrology.calibration."""
