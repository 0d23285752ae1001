"""The decision's thresholds and the advice that separates confounded causes."""

from __future__ import annotations

from metrology.core.effects import REGISTRY

__all__ = ["THRESHOLDS", "ADVICE"]

#: decision thresholds (family-wise levels, Bonferroni-split over the candidates / tests),
#: set a priori and checked on null data (benchmarks/study_blind.py; results in benchmarks/results/)
THRESHOLDS = {
    "alpha_candidates": 0.01,  # family-wise level of the in-sample F-tests over all candidates
    "alpha_heldout": 0.05,  # level of the one-sided held-out gain test (confirms the F-test)
    "alpha_battery": 0.01,  # family-wise level of the noise-model tests on the residuals
    "alpha_outlier": 0.01,  # family-wise level of the largest standardised residual
    "alpha_confound": 0.05,  # runner-up's gain not distinguishable from the winner's at this level
    "corr_confound": 0.95,  # |correlation| of a component parameter with a base parameter
    "alpha_order": 0.05,  # a richer member of a family must predict held-out poses better at this level
    "alpha_form": 0.01,  # level of the datum cloud's form against the readings' (disagreement)
    "alpha_high": 0.01,  # confidence high: every cause named has a held-out p given the others below this
    # a random pose error's within-pose covariance must gain this much (twice the log-likelihood) over
    # excess variance on one sensor alone: a margin between non-nested models, not a test at a known level
    "lr_one_sensor": 3.84,
}

#: the poses that separate each cause from the others (read from the effect registry)
ADVICE = {name: cls.advice for name, cls in REGISTRY.items()}
