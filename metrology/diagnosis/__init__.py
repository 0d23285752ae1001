"""Diagnosis: what the simple model misses, named from the effect registry, extended and measured
on held-out poses. The figures live in :mod:`metrology.report.diagnose`, the file job in
:mod:`metrology.jobs.diagnose`."""

from metrology.diagnosis.candidates import candidates_for, covariates_for
from metrology.diagnosis.datum import datum_form
from metrology.diagnosis.decide import Diagnosis, diagnose
from metrology.diagnosis.fit import Fit, fit
from metrology.diagnosis.heldout import HeldOut, kfold
from metrology.diagnosis.stats import THRESHOLDS, ljung_box, noise_tests, structure

__all__ = [
    "Diagnosis", "diagnose", "Fit", "fit", "HeldOut", "kfold", "THRESHOLDS",
    "candidates_for", "covariates_for", "datum_form", "ljung_box", "noise_tests", "structure",
]
