"""A layout's head terms in the production loop: the readings corrected, and the terms' share of U95.

Where readings enter a batch (:func:`metrology.measure.holes.measure_batch`, the controller's
:func:`metrology.measure.surface.surface_normal`, ``metro normals``) they pass through
:func:`apply_terms`: the temperature from the log's ``temperature_c`` column, and the terms removed by
:func:`metrology.core.effects.apply.remove_terms`, the one implementation ``metro normals`` uses too
(each beam's incidence from the hole's own micro-plane of the raw readings; a row whose covariate is
not known has its term-bearing readings blanked).

**The terms in U95** (the Budget source ``"effects"``): the parameters ``theta`` of the terms
were estimated with the sensors' chart parameters ``beta`` (jointly, by ``diagnose --out`` or
``calibrate``); their joint covariance has blocks ``C_bb`` (the layout's ``covariance``), ``C_bt``
and ``C_tt``. The corrected reading ``d0_i`` moves by ``J_i dtheta`` and the point's height along
the micro-plane's normal by ``(m.u_i) J_i dtheta`` (``m = (-g_x, -g_y, 1)``). A gain and the zero
along its beam trade almost exactly (a run's readings fix ``z + k d`` at their centre), so the
marginal ``C_bb`` is large and cancels against the cross term: propagated as two sums it loses
the small difference. The joint covariance is split instead into two positive parts,

    C_b|t = C_bb - C_bt C_tt^-1 C_tb             the calibration given the terms: the layout's
                                                  covariance the normals propagate (Budget source
                                                  "calibration"),
    var_effects = v^T C_tt v,   v = a_t + C_tt^-1 C_tb a_b,

with ``w_i`` the angle's change per unit height of point ``i`` (``c^T P_i``, ``P`` the
micro-plane estimator's own map, :func:`metrology.measure.estimator.fit_tilt`, with its weights),
``r_i`` the base chart's height rows, ``a_t = sum_i w_i (m.u_i) J_i`` and ``a_b = (w_i r_i)_i``:
their sum is the joint covariance propagated exactly. The
terms' part enters each hole's budget as the source ``"effects"`` (its 2 x 2 covariance of the
slopes, :func:`effects_slope_cov`), and :func:`metrology.measure.budget.combine` makes the angle's
U95 from every source, as for any other.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np

from metrology.core.model import direction_basis

if TYPE_CHECKING:
    from metrology.core.effects.apply import Corrected

__all__ = ["EFFECTS", "Applied", "apply_terms", "check_log", "surface_normal", "micro_normals", "effects_slope_cov", "INCIDENCE_PASSES", "TEMPERATURE_COLUMN"]  # noqa: F822 (micro_normals, INCIDENCE_PASSES: by __getattr__)

_FROM_APPLY = ("INCIDENCE_PASSES", "micro_normals")


def __getattr__(name):
    """The names this module passes on from :mod:`metrology.core.effects.apply`, imported on first use:
    a layout without terms (the usual) never loads the terms' classes (``metro measure``'s start)."""
    if name in _FROM_APPLY:
        from metrology.core.effects import apply

        return getattr(apply, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


#: the calibration's covariance given the terms is taken as block diagonal (sensors independent) when the
#: layout's is and its cross-sensor entries are below this share of its largest (rounding of the joint fit)
OFF_BLOCK_RTOL = 1e-9
#: the name of the terms' source in a hole's budget (:class:`metrology.measure.budget.Source`)
EFFECTS = "effects"
#: the hole log's column a temperature coefficient reads (deg C)
TEMPERATURE_COLUMN = "temperature_c"


@dataclass(frozen=True)
class Applied:
    """A batch's readings with the layout's terms removed (:func:`apply_terms`).

    d : (N, n) float, mm, corrected readings; corrected : Corrected or None (no terms);
    layout : SensorLayout, the layout whose terms were applied
    """

    d: np.ndarray
    corrected: Corrected | None
    layout: object

    @property
    def normals_layout(self):
        """The layout the normals are computed with: its ``covariance`` the calibration's given the
        terms (``C_b|t``, the module docstring); the layout itself without terms."""
        t = self.layout.effects
        if self.corrected is None or self.layout.covariance is None:
            return self.layout
        cond = self.layout.covariance - t.cross @ self._gain()
        cond = 0.5 * (cond + cond.T)
        # a joint fit of terms on single sensors leaves the sensors independent (its covariance block
        # diagonal up to rounding): kept exactly so, the normals propagate it block by block (fast)
        n = self.layout.n
        block = np.kron(np.eye(n, dtype=bool), np.ones((5, 5), bool))
        off = np.abs(np.where(block, 0.0, cond)).max()
        if off <= OFF_BLOCK_RTOL * np.abs(np.where(block, cond, 0.0)).max() and not np.any(
                np.where(block, 0.0, self.layout.covariance)):
            cond = np.where(block, cond, 0.0)
        return replace(self.layout, covariance=cond)

    def _gain(self):
        """``(k, 5n)``: ``C_tt^-1 C_tb``."""
        t = self.layout.effects
        return np.linalg.pinv(t.cov, hermitian=True) @ t.cross.T

    def widen(self, h, sub, rows, mask):
        """``h`` (a :class:`~metrology.measure.normals.HoleNormals` of the holes ``rows`` measured on
        the sensors ``mask`` (n,) bool, sub-layout ``sub``) with the terms' share of the tilt's covariance
        added to its budget as the source :data:`EFFECTS` and its angle's uncertainty made again by
        :func:`metrology.measure.budget.combine` (the module docstring); ``h`` unchanged without terms."""
        from metrology.measure.budget import Source, combine

        if self.corrected is None:
            return h
        cols = [5 * i + j for i in np.flatnonzero(mask) for j in range(5)]
        (c00, c01, c11), _ = effects_slope_cov(sub, self.d[np.ix_(rows, np.flatnonzero(mask))], h.normal,
                                               self.corrected.jac[rows][:, mask], self.layout.effects.cov,
                                               self._gain()[:, cols])
        budget = h.budget.with_source(Source(EFFECTS, np.stack([c00, c01, c11], axis=1)))
        un = combine(budget)
        return replace(h, u_angle=un.u, U95=un.U95, budget=budget)


def effects_slope_cov(layout, d, normal, jac, C_tt, gain):
    """``(c00, c01, c11)`` each ``(N,)``: the terms' share of the covariance of the micro-plane's slopes
    ``(g_x, g_y)`` (the Budget source "effects": ``P_v C_tt P_v^T``, ``P_v`` the slopes' change per unit
    term parameter, base-correlated part included; module docstring), for holes read ``d (N, n)`` mm by
    ``layout``'s sensors, normals ``normal (N, 3)``, sensitivities ``jac (N, n, k)`` mm per parameter,
    the terms' covariance ``C_tt (k, k)`` and ``gain (k, 5n)``, ``C_tt^-1 C_tb`` on these sensors' chart
    parameters. Also returns ``(g_x, g_y)``."""
    from metrology.measure.estimator import fit_tilt

    u = layout.direction
    nz = normal[:, 2]
    gx, gy = -normal[:, 0] / nz, -normal[:, 1] / nz
    dT = d.T  # (n, N)
    e = direction_basis(u)  # (n, 2, 3)
    # P_i: the slopes' change per unit height of point i, the micro-plane estimator's own map (its weights), (n, N)
    A = fit_tilt(layout, d).A  # (N, 2, n): the slopes' change per unit change of each height, sign opposite
    P = (-A[:, 0, :].T, -A[:, 1, :].T)
    v = [np.zeros((len(d), jac.shape[2])), np.zeros((len(d), jac.shape[2]))]
    # only the sensors the terms act on or correlate with (a term's own sensor, in a joint fit) contribute
    for i in sorted(set(np.flatnonzero(np.any(gain != 0, axis=0)) // 5) | set(np.flatnonzero(np.any(jac != 0, axis=(0, 2))))):
        mu = u[i, 2] - gx * u[i, 0] - gy * u[i, 1]
        r = np.stack([-gx, -gy, np.ones_like(gx)] + [dT[i] * (e[i, j, 2] - gx * e[i, j, 0] - gy * e[i, j, 1])
                                                     for j in range(2)], axis=1)  # (N, 5): height rows
        t = (mu[:, None] * jac[:, i, :]) + r @ gain[:, 5 * i:5 * i + 5].T  # (N, k)
        for a, p in zip(v, P):
            a += p[i][:, None] * t
    c = [np.einsum("Nk,kl,Nl->N", a, C_tt, b) for a, b in ((v[0], v[0]), (v[0], v[1]), (v[1], v[1]))]
    return tuple(np.where(np.isfinite(x), x, 0.0) for x in c), (gx, gy)


def apply_terms(layout, d, table=None, temp_c=None, what="the log", shape=None) -> Applied:
    """The readings ``d (N, n)`` mm of ``layout``'s sensors with its terms removed (:class:`Applied`).

    The temperature is ``temp_c (N,)`` deg C, else the ``temperature_c`` column of ``table`` (a
    pyarrow Table of the same rows) when a term needs it; a term whose covariate is missing raises
    ValueError naming the column (``what`` names the source). ``shape (N, 3, 3)`` 1/mm TCS, each row's local
    surface where the panel is known (``measure --panel``): each beam's incidence at its own spot."""
    terms = layout.effects
    if terms is None:
        return Applied(d, None, layout)
    needs = terms.needs()
    if "temperature_c" in needs and temp_c is None:
        if table is None or TEMPERATURE_COLUMN not in table.column_names:
            raise ValueError(f"{what} has no {TEMPERATURE_COLUMN} column (deg C): the layout's temperature "
                             f"coefficient ({', '.join(c.label for c in terms.components if c.name == 'drift')}) "
                             f"needs the temperature of every hole")
        col = table.column(TEMPERATURE_COLUMN)
        temp_c = np.asarray(col.cast("float64").to_numpy(zero_copy_only=False), float)
    from metrology.core.effects.apply import remove_terms  # a layout with terms only (not `measure`'s usual path)

    return Applied((corr := remove_terms(layout, d, temp_c, what, shape)).d, corr, layout)


def check_log(layout, log) -> None:
    """Refuse a hole log (:class:`metrology.io.holelog_reader.HoleLog`) that lacks a covariate the layout's
    terms need, naming the column and the partition, before a hole is measured."""
    if layout.effects is None or "temperature_c" not in layout.effects.needs():
        return
    labels = ", ".join(c.label for c in layout.effects.components if c.name == "drift")
    for part in log.partitions:
        if TEMPERATURE_COLUMN not in log.columns(part):
            raise ValueError(f"{log.where(part)}: no {TEMPERATURE_COLUMN} column (deg C): the layout's temperature "
                             f"coefficient ({labels}) needs the temperature of every hole")


def surface_normal(layout, d, shape, temp_c=None):
    """The controller's per-hole call (:func:`metrology.measure.surface.surface_normal`, the contract
    there) with the layout's head terms removed from the readings ``d (h, n)`` mm first; ``temp_c (h,)``
    deg C, the head's temperature, for a temperature coefficient (ValueError naming it when missing).
    ``metrology.measure.surface_normal`` is this function."""
    from metrology.measure.surface import surface_normal as plain

    if layout.effects is None:
        return plain(layout, d, shape)
    d = np.asarray(d, float)
    single = d.ndim == 1
    dd = d.reshape(-1, layout.n)
    K = np.broadcast_to(np.asarray(shape, float).reshape(-1, 3, 3), (len(dd), 3, 3))  # each spot's incidence on it
    dd = apply_terms(layout, dd, temp_c=None if temp_c is None else np.atleast_1d(temp_c), what="surface_normal",
                     shape=K).d
    return plain(replace(layout, effects=None), dd[0] if single else dd, shape)
