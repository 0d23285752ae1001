"""Sensor calibration: the estimators, the dataset they read, identifiability, convergence and validation."""

from metrology.calibration.calibrate import DEFAULT_METHOD, CalibrationReport, calibrate_dataset
from metrology.calibration.convergence import batch_convergence, residual_table
from metrology.calibration.dataset import Dataset, load_dataset
from metrology.calibration.estimators import METHODS, Calibration, calibrate
from metrology.calibration.identifiability import Identifiability, describe_combination, identifiability, sigma_words
from metrology.calibration.validation import ValidationReport, validate

__all__ = [
    "DEFAULT_METHOD", "CalibrationReport", "calibrate_dataset",
    "batch_convergence", "residual_table",
    "Dataset", "load_dataset",
    "METHODS", "Calibration", "calibrate",
    "Identifiability", "describe_combination", "identifiability", "sigma_words",
    "ValidationReport", "validate",
]
