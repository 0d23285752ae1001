"""Small descriptive statistics shared by every report and test: one home for max / mean / std and the robust scale."""

from __future__ import annotations

import math

import numpy as np


def describe(values, suffix: str = "_deg", p95: bool = False, count: bool = False) -> dict:
    """Max, mean and sample standard deviation of the finite ``values``.

    Parameters
    ----------
    values : (m,) float, in the unit that ``suffix`` names (``_deg``: degrees)
        Non-finite entries (points not measured) are left out.
    suffix : str
        Appended to each key: ``max<suffix>``, ``mean<suffix>``, ``std<suffix>``.
    p95 : bool
        Add the 95th percentile as ``p95<suffix>``.
    count : bool
        Add ``n``, the number of finite values, first.

    Returns
    -------
    dict
        ``std`` has ``ddof=1`` (0.0 for one value); every entry is NaN when no value is finite.
    """
    v = np.asarray(values, dtype=float).ravel()
    v = v[np.isfinite(v)]
    out = {"n": int(len(v))} if count else {}
    empty = not len(v)
    out[f"max{suffix}"] = math.nan if empty else float(v.max())
    out[f"mean{suffix}"] = math.nan if empty else float(v.mean())
    out[f"std{suffix}"] = math.nan if empty else (float(v.std(ddof=1)) if len(v) > 1 else 0.0)
    if p95:
        out[f"p95{suffix}"] = math.nan if empty else float(np.percentile(v, 95))
    return out


#: 1 / Phi^-1(3/4): the median absolute deviation of a normal sample times this estimates its sigma
#: (``scipy.stats.median_abs_deviation(..., scale="normal")`` to five digits, without importing scipy)
MAD_NORMAL = 1.4826


def robust_sigma(x, about=None) -> float:
    """The normal-consistent robust scale ``1.4826 median|x - c|`` of the finite ``x``: ``c`` their
    median, or ``about`` (0 for residuals already centred by a fit). NaN when no value is finite."""
    v = np.asarray(x, dtype=float).ravel()
    v = v[np.isfinite(v)]
    if v.size == 0:
        return math.nan
    c = float(np.median(v)) if about is None else float(about)
    return MAD_NORMAL * float(np.median(np.abs(v - c)))
