"""Diagnosis: what the simple model misses, which catalogued effect it is, and the gain.

The procedure (issue 6):

1. **Discrepancy.** Calibrate the base model (5 chart parameters per sensor, batch least
   squares weighted by the stated ``noise_mm``). Side by side: what the simulation predicts
   for this data set (the same poses and layout, the stated noise, analysed the same way)
   and what the measurements give: in-sample residual RMS per sensor and the k-fold held-out
   normal deviation. The residuals are tested against the noise model (chi-square per sensor
   against ``noise_mm``, Ljung-Box whiteness in pose order, Shapiro-Wilk normality, and the
   correlation of sensors within a pose), and their structure is tabulated against the
   reading, the incidence angle, time, temperature, the spot on the datum and pose index.
2. **Candidates.** Every catalogued component (per sensor where it belongs to one sensor)
   is added to the base model and scored: an in-sample F-test of the nested models and the
   k-fold-by-pose held-out gain (a one-sided paired t-test on the per-pose held-out
   chi-square of the candidate's sensors, base against extended). A candidate is *significant* when both
   p-values are below the thresholds of :data:`THRESHOLDS`; the named cause is the
   significant candidate with the largest held-out chi-square reduction. ``none``: no
   significant candidate and residuals consistent with the noise model; ``unexplained``:
   residuals inconsistent with the noise model and either no significant candidate or the
   best one leaves them inconsistent (it is reported as a partial explanation).
   Confounding: a runner-up whose held-out gain cannot be told from the winner's, and the
   correlation of the component's parameters with the base parameters, are reported with
   the poses that would separate them.
3. **Extension.** The named component is re-identified with the base parameters; each extra
   parameter comes with its standard error (``s^2 (J^T J)^-1``). The extended model drives
   the simulator, and the side-by-side table is repeated with it.
4. **Gain.** k-fold by pose: held-out residual RMS (a per-pose value predicted from the
   other sensors of its pose) and normal angular deviation, base against extended, and their ratio.

The modules: :mod:`~metrology.diagnosis.fit` (the extended fit, its solver and its kept results),
:mod:`~metrology.diagnosis.stats` (the noise-model battery, the structure table),
:mod:`~metrology.diagnosis.heldout` (k-fold by pose), :mod:`~metrology.diagnosis.candidates`
(covariates, the registry's candidates, their scores), :mod:`~metrology.diagnosis.extension`
(the named component, the side-by-side simulation), :mod:`~metrology.diagnosis.datum` (the
datum cloud's form against the readings'), :mod:`~metrology.diagnosis.select` (the forward
selection, a ``Selection``), :mod:`~metrology.diagnosis.judge` (the verdict, a ``Judge``),
:mod:`~metrology.diagnosis.rules` (the decision rules in the order they apply),
:mod:`~metrology.diagnosis.decide` (the steps in sequence and the one-paragraph summary).
Words and figures are in :mod:`metrology.report.diagnose`, the file job in
:mod:`metrology.jobs.diagnose`.
"""

from metrology.diagnosis.candidates import CandidateResult, candidates_for, covariates_for, flag_outliers
from metrology.diagnosis.datum import DatumFormCheck, FormAgreement, datum_form, form_agreement
from metrology.diagnosis.decide import Diagnosis, diagnose
from metrology.diagnosis.fit import Fit, FitData, FitOptions, fit, fit_any
from metrology.diagnosis.heldout import HeldOut, kfold
from metrology.diagnosis.stats import NoiseTests, Trend, battery_on, ljung_box, noise_tests, structure
from metrology.diagnosis.thresholds import ADVICE, THRESHOLDS

__all__ = ["THRESHOLDS", "ADVICE", "Fit", "FitData", "FitOptions", "fit", "fit_any", "Diagnosis", "diagnose", "CandidateResult", "candidates_for",
           "covariates_for", "flag_outliers", "DatumFormCheck", "FormAgreement", "datum_form", "form_agreement", "HeldOut",
           "kfold", "NoiseTests", "Trend", "ljung_box", "noise_tests", "battery_on", "structure"]
