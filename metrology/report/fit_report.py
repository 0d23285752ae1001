"""A fit report in lmfit's style (``lmfit.printfuncs.fit_report``): the fit statistics, each
parameter with its standard error and relative error, and the correlations above a stated
cut-off only.

``metro calibrate`` prints one per sensor (each sensor's five parameters are one fit);
``metro diagnose`` one for the extension it names. The cut-off is
:data:`metrology.core.tolerances.CORRELATION_REPORT` (|r| > 0.5; lmfit's 0.1 lists nearly
every pair of these fits).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from metrology.core.tolerances import CORRELATION_REPORT

__all__ = ["FitSummary", "fit_report", "correlations_from_cov"]


@dataclass(frozen=True)
class FitSummary:
    """What a fit report shows.

    title : str; method : str; ndata : int, readings fitted; nvarys : int, free parameters;
    chisqr : float, sum of (residual / stated noise)^2; params : tuple of (name, value,
    stderr, unit) in display units; correlations : tuple of (name_a, name_b, r), every pair;
    sensor : str or None, the sensor whose fit it is (None: a fit of several, the diagnosis's)
    """

    title: str
    method: str
    ndata: int
    nvarys: int
    chisqr: float
    params: tuple
    correlations: tuple = ()
    sensor: str | None = None

    @property
    def nfree(self) -> int:
        return self.ndata - self.nvarys

    @property
    def redchi(self) -> float:
        return self.chisqr / self.nfree if self.nfree > 0 else math.nan

    def correl_above(self, min_correl: float = CORRELATION_REPORT) -> list:
        """The pairs with |r| > ``min_correl``, largest |r| first."""
        return sorted((c for c in self.correlations if abs(c[2]) > min_correl), key=lambda c: -abs(c[2]))

    def param_rows(self) -> list:
        """(name, value, stderr, relative error in %, unit) as strings."""
        rows = []
        for name, value, stderr, unit in self.params:
            if stderr is None or not np.isfinite(stderr):
                se, rel = "not determined", ""
                rows.append((name, f"{value:+.5g}", se, rel, unit))
                continue
            dec = max(0, 1 - math.floor(math.log10(stderr))) if stderr > 0 else 4  # two digits of the error
            se = f"{stderr:.{dec}f}"
            rel = f"{100 * abs(stderr / value):.1f} %" if value != 0 else "inf"
            rows.append((name, f"{value:+.{dec}f}", se, rel, unit))
        return rows


def correlations_from_cov(cov, names) -> tuple:
    """Every pair's correlation from a covariance ``(k, k)``: tuple of (a, b, r); pairs with a
    zero variance are skipped."""
    cov = np.asarray(cov, dtype=float)
    se = np.sqrt(np.maximum(np.diag(cov), 0.0))
    out = []
    for a in range(len(names)):
        for b in range(a + 1, len(names)):
            if se[a] > 0 and se[b] > 0:
                out.append((names[a], names[b], float(cov[a, b] / (se[a] * se[b]))))
    return tuple(out)


def fit_report(fit: FitSummary, min_correl: float = CORRELATION_REPORT) -> str:
    """The report, in lmfit's layout."""
    lines = [f"[[Fit Statistics]] {fit.title}",
             f"    # fitting method   = {fit.method}",
             f"    # data points      = {fit.ndata}",
             f"    # variables        = {fit.nvarys}",
             f"    chi-square         = {fit.chisqr:.5g}",
             f"    reduced chi-square = {fit.redchi:.5g}",
             "[[Variables]]"]
    w = max((len(p[0]) for p in fit.params), default=4)
    for name, value, se, rel, unit in fit.param_rows():
        err = f"+/- {se}" if rel else f"({se})"
        lines.append(f"    {name + ':':<{w + 1}} {value} {err} {unit}" + (f" ({rel})" if rel else ""))
    above = fit.correl_above(min_correl)
    lines.append(f"[[Correlations]] (unreported correlations are < {min_correl:.3f})")
    if not above:
        lines.append("    none")
    for a, b, r in above:
        lines.append(f"    C({a}, {b}) = {r:+.4f}")
    return "\n".join(lines)
