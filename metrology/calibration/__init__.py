"""Sensor calibration: the estimators, the dataset they read, identifiability and validation."""

from metrology.calibration.calibrate import DEFAULT_METHOD, CalibrationReport, calibrate_dataset
from metrology.calibration.dataset import Dataset, load_dataset
from metrology.calibration.estimators import METHODS, Calibration, calibrate
from metrology.calibration.identifiability import Identifiability, identifiability
from metrology.calibration.validation import ValidationReport, validate

__all__ = [
    "DEFAULT_METHOD", "CalibrationReport", "calibrate_dataset",
    "Dataset", "load_dataset",
    "METHODS", "Calibration", "calibrate",
    "Identifiability", "identifiability",
    "ValidationReport", "validate",
]
