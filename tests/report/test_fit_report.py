"""The diagnose fit report's statistics: chi-square and dof of the same readings (the fitted
sensors'), so the reduced chi-square reads against the stated noise."""

from __future__ import annotations

import numpy as np
from scipy import stats

from metrology.core.effects import Drift
from metrology.diagnosis import FitData, fit_any
from tests.diagnosis.helpers import small_case


def test_extension_fit_chi2_and_dof_cover_the_same_readings():
    """A drift fitted on L3 alone of a simulated run with white noise at the stated level: the
    fit's chi-square is L3's residuals over L3's noise, its dof L3's readings less six
    parameters, and their ratio is one within the chi-square distribution's 99.9 % band
    (it was about four when the other three sensors' chi-square was added to L3's dof)."""
    ds, cov = small_case(3, 40)
    sigma = ds.layout.noise_mm
    f = fit_any(FitData(ds.layout, ds.obs, cov, sigma), (Drift((2,), [0.0], names=ds.layout.names, variable="temp"),), None)
    assert f.sensors == (2,)
    m = int(np.isfinite(ds.obs.d[:, 2]).sum())
    assert f.dof == m - 6
    assert np.isclose(f.chi2, np.nansum((f.residual[:, 2] / sigma[2]) ** 2), rtol=1e-9)
    lo, hi = stats.chi2.ppf([0.0005, 0.9995], f.dof)
    assert lo < f.chi2 < hi, (f.chi2, f.dof)
