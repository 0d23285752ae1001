"""The base of the effect catalogue: the covariates an effect depends on and :class:`Component`.

A registry entry (:data:`metrology.core.effects.REGISTRY`) is one :class:`Component` subclass;
its class attributes and classmethods are everything the consumers (candidates, advice, plots,
the simulator, the text report) read about the effect.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

__all__ = ["Covariates", "Component", "VERDICTS", "SECONDS_PER_HOUR", "REFERENCE_TEMP_C", "LAG_FRACTIONS",
           "lagged_temperature"]

#: the two verdicts of a diagnosis that name no catalogued effect
VERDICTS = ("none", "unexplained")
SECONDS_PER_HOUR = 3600.0
#: reference temperature of dimensional metrology (ISO 1), deg C
REFERENCE_TEMP_C = 20.0
#: time constants of the thermal lags of ``drift@lag``, as fractions of the run's duration
LAG_FRACTIONS = (0.05, 0.15)


def lagged_temperature(time_h, temp_c, fractions=LAG_FRACTIONS):
    """The temperature ``temp_c (p,)`` deg C at times ``time_h (p,)`` h (in pose order) seen
    through first-order lags ``tau dy/dt = T - y``, ``y(0) = T(0)``, of time constants
    ``fractions`` of the run's duration; ``T`` linear between samples (exact recursion).
    Returns ``(p, len(fractions))`` deg C, or None without temperature or duration.

    A sensor head and its mount reach the air's temperature through their heat capacity: the
    zero follows the temperature with a lag of minutes, which neither the temperature itself
    nor a smooth function of time describes (a lagged air-conditioning cycle, a warm-up then a
    cool-down). Two time constants span the lags in between by their combination.
    """
    t = np.asarray(time_h, float)
    T = np.asarray(temp_c, float)
    span = float(np.ptp(t)) if len(t) else 0.0
    if not np.all(np.isfinite(T)) or not np.all(np.isfinite(t)) or span <= 0 or np.ptp(T) <= 0 \
            or np.any(np.diff(t) < 0):
        return None
    out = np.empty((len(t), len(fractions)))
    for j, f in enumerate(fractions):
        tau = f * span
        y = np.empty_like(T)
        y[0] = T[0]
        for k in range(1, len(t)):
            h = t[k] - t[k - 1]
            if h <= 0:
                y[k] = y[k - 1] + (T[k] - T[k - 1])
                continue
            a, r = np.exp(-h / tau), (T[k] - T[k - 1]) / h
            y[k] = T[k] - r * tau + (y[k - 1] - T[k - 1] + r * tau) * a
        out[:, j] = y
    return out


@dataclass(frozen=True)
class Covariates:
    """What the effects depend on, per pose and reading, besides ``d0``.

    Attributes
    ----------
    time_h : (p,) float, h, since the first pose (pose index when the export has no time)
    temp_c : (p,) float, deg C; NaN where the export has none
    cos_inc : (p, n) float, |cos| of the beam's incidence angle on the datum (unitless)
    inv_nu : (p, n) float, 1 / (N_tcs . u) (signed; ``dd/dw`` for a datum displaced by ``w``)
    spot_st : (p, n, 2) float, mm, spot position on the datum in the plane's own axes
        (tracker frame), relative to the datum centre
    range_mm : (n, 2) float, mm, the readings' normalisation interval ``[lo, hi]``
    scan_w : (p, n) float, mm, or None: the datum's deviation from its plane at each spot as
        the tracker scanned it (a local fit to the datum cloud; None without a cloud)
    scan_ptp_mm : float, mm, the scanned deviation's peak-to-valley over the cloud beyond its own
        best plane (NaN without)
    scan_ptp_se_mm : float, mm, its standard error (the scan surface's at its two extremes, and the
        change of the peak-to-valley at the next degree of the surface, the one below at the top)
    d_span : (n, 2) float, mm, or None: the span of the readings each sensor gave (min, max)
    temp_lag : (p, m) float, deg C, or None: the temperature history seen through first-order
        lags of time constants :data:`LAG_FRACTIONS` of the run (:func:`lagged_temperature`;
        computed once over the whole run, so a subset of poses keeps its own history)
    """

    time_h: np.ndarray
    temp_c: np.ndarray
    cos_inc: np.ndarray
    inv_nu: np.ndarray
    spot_st: np.ndarray
    range_mm: np.ndarray
    scan_w: np.ndarray | None = None
    scan_ptp_mm: float = float("nan")
    scan_ptp_se_mm: float = 0.0
    d_span: np.ndarray | None = None
    temp_lag: np.ndarray | None = None

    @property
    def n_poses(self) -> int:
        return len(self.time_h)

    def select(self, idx) -> "Covariates":
        """The poses ``idx``."""
        return replace(self, time_h=self.time_h[idx], temp_c=self.temp_c[idx], cos_inc=self.cos_inc[idx],
                       inv_nu=self.inv_nu[idx], spot_st=self.spot_st[idx],
                       scan_w=None if self.scan_w is None else self.scan_w[idx],
                       temp_lag=None if self.temp_lag is None else self.temp_lag[idx])

    @classmethod
    def from_geometry(cls, zero, direction, normal_tcs, offset_tcs, tcs2tracker_rot, tcs2tracker_trans,
                      plane_normal, plane_centre, range_mm, time_s=None, temp_c=None):
        """Covariates of sensors ``(zero, direction)`` on the datum seen from each pose.

        Parameters
        ----------
        zero : (n, 3) float, mm, TCS
        direction : (n, 3) float, unit, TCS
        normal_tcs : (p, 3) float, unit, TCS; offset_tcs : (p,) float, mm
        tcs2tracker_rot : (p, 3, 3) float; tcs2tracker_trans : (p, 3) float, mm, tracker frame
        plane_normal : (3,) float, unit, tracker frame
        plane_centre : (3,) float, mm, tracker frame, a point of the datum (its centre)
        range_mm : (n, 2) float, mm
        time_s : (p,) float, s, or None (then the pose index stands for time, "hours" = index)
        temp_c : (p,) float, deg C, or None
        """
        from metrology.core.frames import points_tracker_from_tcs
        from metrology.core.model import readings
        from metrology.core.plane import plane_basis

        p = len(offset_tcs)
        d, _ = readings(zero, direction, normal_tcs, offset_tcs)
        nu = normal_tcs @ np.asarray(direction, float).T  # (p, n)
        spot_tcs = zero[None] + d[..., None] * direction[None]
        spot = points_tracker_from_tcs(spot_tcs, tcs2tracker_rot, tcs2tracker_trans)
        basis = plane_basis(plane_normal)  # (2, 3)
        spot_st = np.einsum("pnj,kj->pnk", spot - np.asarray(plane_centre, float), basis)
        if time_s is None or not np.all(np.isfinite(time_s)):
            time_h = np.arange(p, dtype=float)
        else:
            time_h = (np.asarray(time_s, float) - float(np.min(time_s))) / SECONDS_PER_HOUR
        temp = np.full(p, np.nan) if temp_c is None else np.asarray(temp_c, float)
        return cls(time_h, temp, np.abs(nu), 1.0 / nu, spot_st, np.asarray(range_mm, float),
                   temp_lag=lagged_temperature(time_h, temp))


@dataclass(frozen=True)
class Component:
    """Base class: a named effect with parameters, acting on the sensors ``sensors``.

    Attributes
    ----------
    sensors : tuple of int
        Indices of the sensors the term acts on; empty for an effect of the set-up (it acts on
        every sensor).
    values : (k,) float, the parameters, in :attr:`param_units`
    stderr : (k,) float or None, after a fit
    names : tuple of str, the layout's sensor names (for labels)
    """

    sensors: tuple = ()
    values: np.ndarray | None = None
    stderr: np.ndarray | None = None
    names: tuple = ()

    name = "component"
    param_names = ()
    param_units = ()
    #: its parameters are one per pose (re-estimated on held-out poses, not predicted)
    per_pose = False
    #: the term depends on d0
    uses_d0 = False

    # -- the registry entry (what every consumer reads about the effect) ----------------
    #: the poses that separate this effect from the others (the diagnosis' advice)
    advice = ""
    #: what ``size`` means for the simulator (:mod:`metrology.sim.synth`)
    size_meaning = ""
    #: the covariate its residual plot is drawn against (a key of the structure table)
    plot_key = "pose_index"
    #: the residual plot draws the fitted term over the base residuals
    plot_term = True
    #: the parameters the text report prints (empty: all of them)
    key_params = ()
    #: an effect of the set-up (acts on every sensor; the simulator takes no sensor for it)
    setup = False
    #: how many positions :meth:`locate` chose among (the in-sample test is Bonferroni-split
    #: over them); 1 for an effect with nothing to locate
    searched = 1
    #: what the diagnosis' ``detectable`` size of the family measures
    detectable_meaning = ""
    #: the family its members compete in (one place per family and sensors); empty: its :attr:`name`
    family = ""
    #: terms outside the catalogue it can be mistaken for, each checked before it is named
    #: (``"crosstalk"``: a shift with another sensor's distance, :mod:`metrology.diagnosis.crosstalk`)
    confused_with = ()
    #: its term is the same as leaving readings out: it predicts nothing held out, so the held-out
    #: tests of the verdict do not judge it
    drops_readings = False
    #: the fit holds the base geometry where it was put (a rigid pose error, see ``PoseError``)
    holds_base = False
    #: its detectable size is that of the least favourable of :meth:`detectable_shapes`, each by
    #: the best of the family's members (its members' shapes vary most)
    worst_shape = False

    @property
    def tie_rank(self) -> int:
        """Between two members of a family with as many parameters, the smaller rank is taken
        (the physical cause before its proxy); 1 unless the effect says otherwise."""
        return 1

    @classmethod
    def candidates_for_sensor(cls, i, names, cov) -> list:
        """The candidates of this effect on sensor ``i`` (values zero): one, unless the effect
        belongs to the set-up (:attr:`setup`)."""
        return [] if cls.setup else [cls((i,), names=names)]

    @classmethod
    def candidates_for_setup(cls, names, cov, flags=None) -> list:
        """The candidates of this effect that are not per sensor (values zero); none by default.
        ``flags`` (p, n) bool: readings flagged as gross, or None."""
        return []

    def locate(self, residual, cov, sigma) -> "Component":
        """The candidate placed where the data put it, before it is fitted: an effect with a
        location in the run (a change point) finds it in the residuals ``(p, n)`` mm of the model
        it is scored against (``sigma (n,)`` mm the stated noise) and sets :attr:`searched`. By
        default nothing to locate: ``self``."""
        return self

    def size_rows(self, d0, cov):
        """``(B (m, k), meaning)``: the rows whose fitted values give the effect's size in its
        family's unit (one row: its absolute value; several: their peak-to-valley), or None where
        the effect defines none."""
        return None

    def size(self, C, d0, cov) -> dict | None:
        """The size in the family's unit with its standard error (delta method on ``C (k, k)``,
        the covariance of :attr:`values`): ``{"value", "stderr", "unit", "meaning"}`` from
        :meth:`size_rows`, or None where the effect defines none. ``d0 (p, n)`` mm, the base readings."""
        rows = self.size_rows(d0, cov)
        if rows is None:
            return None
        B, meaning = rows
        e = B @ self.values
        if len(e) == 1:
            val, g = abs(float(e[0])), B[0]
        else:
            hi_, lo_ = int(np.argmax(e)), int(np.argmin(e))
            val, g = float(e[hi_] - e[lo_]), B[hi_] - B[lo_]
        se = float(np.sqrt(max(g @ C @ g, 0.0))) if C.shape == (len(g), len(g)) else None
        return {"value": val, "stderr": se, "unit": "mm", "meaning": meaning}

    def detectable_direction(self):
        """``(k,)`` float: the unit shape of its parameters whose size the diagnosis' detectable
        size reports for this member, or None where this member has none."""
        return None

    @classmethod
    def detectable_shapes(cls, d0_i, cos_inc_i, fin) -> list:
        """The family's shapes over which its detectable size is the worst (:attr:`worst_shape`),
        on one sensor: ``[(p,) float]``, each of size 1 in the family's unit, NaN where ``fin (p,)``
        is False; ``d0_i (p,)`` mm its base readings, ``cos_inc_i (p,)`` its incidence cosines."""
        return []

    def nuisance(self) -> "Component | None":
        """The part of the effect that is not the cause (tested against, carried in both models),
        or None."""
        return None

    def geometry_member(self) -> "Component | None":
        """For an effect that holds the base geometry (:attr:`holds_base`), the member whose fit
        places it; None otherwise."""
        return None

    def for_joint_fit(self) -> "Component":
        """The component to refit jointly with the others once named (values cleared)."""
        return replace(self, values=None, stderr=None)

    def detectable_size(self, J_i, cov, fin, sigma_i, alpha) -> float | None:
        """The size (the family's unit) its in-sample test at level ``alpha`` detects at 95 %
        power on sensor ``self.sensors[0]``: ``J_i (p, 5)`` mm per unit parameter, the sensor's
        base Jacobian; ``fin (p,)`` bool, its finite readings; ``sigma_i`` mm. None where the
        effect defines none here (the older families are in :mod:`metrology.diagnosis.detectable`)."""
        return None

    @classmethod
    def hidden(cls, i, size) -> "Component":
        """The component the simulator hides for ``size`` (see :attr:`size_meaning`) on sensor
        ``i`` (None for an effect of the set-up). By default a one-parameter sensor effect
        whose parameter is the size; others say how their size maps to their parameters."""
        if cls.setup or len(cls.param_names) != 1:
            raise ValueError(cls.name)
        return cls((i,), [size])

    def __post_init__(self):
        k = self.n_params
        v = np.zeros(k) if self.values is None else np.asarray(self.values, float).reshape(k)
        object.__setattr__(self, "values", v)
        object.__setattr__(self, "sensors", tuple(int(i) for i in self.sensors))

    # -- parameters --------------------------------------------------------------------
    @property
    def n_params(self) -> int:
        return len(self.param_names)

    @property
    def label(self) -> str:
        """``name`` or ``name.L2``: the prefix of this component's parameter names."""
        if not self.sensors:
            return self.name
        return self.name + "." + "+".join(self.names[i] if self.names else str(i) for i in self.sensors)

    @property
    def full_param_names(self) -> tuple:
        return tuple(f"{self.label}.{p}" for p in self.param_names)

    def with_values(self, values, stderr=None) -> "Component":
        return replace(self, values=np.asarray(values, float), stderr=None if stderr is None else np.asarray(stderr, float))

    def select(self, idx) -> "Component":
        """The component restricted to the poses ``idx`` (only per-pose state changes)."""
        return self

    def _mask(self, n):
        m = np.zeros(n, bool)
        m[list(self.sensors) if self.sensors else slice(None)] = True
        return m

    # -- the term ----------------------------------------------------------------------
    def basis(self, d0, cov: Covariates):
        """``(p, n, k)``: the term is linear in the values, ``f = basis @ values``."""
        raise NotImplementedError

    def evaluate(self, values, d0, cov: Covariates):
        """Additive reading term ``(p, n)`` mm for parameters ``values (k,)``.

        Parameters
        ----------
        values : (k,) float
        d0 : (p, n) float, mm, the base model's readings
        cov : Covariates
        """
        return self.basis(d0, cov) @ np.asarray(values, float)

    def jacobian(self, values, d0, cov: Covariates):
        """``(p, n, k)``: ``df/dvalues`` (every catalogued term is linear in its values)."""
        return self.basis(d0, cov)

    def d_dd0(self, values, d0, cov: Covariates):
        """``(p, n)``: ``df/dd0`` (zero unless the term depends on the reading)."""
        return np.zeros_like(d0)

    def constraint(self, values):
        """Gauge rows ``(r (c,), J (c, k))`` appended to the weighted residuals (none by default)."""
        return np.zeros(0), np.zeros((0, self.n_params))

    def describe(self) -> dict:
        out = {"component": self.name, "label": self.label,
               "sensors": [self.names[i] if self.names else i for i in self.sensors], "params": {}}
        for j, pn in enumerate(self.param_names):
            out["params"][pn] = {"value": float(self.values[j]), "unit": self.param_units[j],
                                 "stderr": None if self.stderr is None else float(self.stderr[j])}
        return out


def _sensor_basis(cols, n, sensors):
    """Place per-sensor columns ``(p, n, k)`` on the chosen sensors only."""
    # np.zeros_like's array (dtype and, for a C-ordered input, order) at a tenth of its cost
    out = np.zeros(cols.shape, cols.dtype) if cols.flags.c_contiguous else np.zeros_like(cols)
    idx = list(sensors)
    out[:, idx] = cols[:, idx]
    return out
