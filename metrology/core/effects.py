"""The catalogue of physical effects that extend the measurement model, as components.

The base model of :mod:`metrology.core.model` predicts a reading ``d0`` from the sensor's zero
point and beam direction and the datum plane in the pose's TCS. Each effect is a small
named component that adds a term to it::

    d = d0(theta) + sum_c f_c(values_c; d0, covariates)                     (mm)

A component has named parameters, a pure :meth:`Component.evaluate` (the additive term,
``(p, n)`` mm, zero on sensors it does not concern), an analytic :meth:`Component.jacobian`
(``(p, n, k)``) and, when the term depends on ``d0``, its derivative ``df/dd0`` (so the
Jacobian of the full model w.r.t. the base parameters is ``(1 + sum df/dd0) J0``).
A :class:`ExtendedModel` is the base geometry plus a list of components; parameter names are
``<component>.<sensor>.<param>`` and a clash raises. The same components drive the simulator
(:mod:`metrology.sim.synth`) and the extended fit (:mod:`metrology.diagnosis.diagnosis`).

Catalogue (formulas with ``gamma`` the beam's incidence angle on the datum, ``N.u`` the cosine
between the TCS plane normal and the beam, ``x = (2 d0 - lo - hi) / (hi - lo)`` the reading
normalised over the sensor's range ``[lo, hi]``):

``scale``        ``k d0``                         gain error of the sensor (unitless ``k``)
``incidence``    ``c tan^2(gamma)``               spot/speckle bias growing with tilt (``c`` mm)
``drift``        ``r (T - 20 C)`` or ``r t``      thermal zero drift (mm/K or mm/h)
``nonlinearity`` ``c2 P2(x) + c3 P3(x)``          linearity error: bow and S-shape (mm)
``plane_form``   ``w(s, t) / (N.u)``, ``w = b_s s + b_t t + b_ss s^2 + b_st s t + b_tt t^2``,
                 ``(s, t)`` the spot's in-plane coordinates on the datum (tracker frame) over
                 ``R``: datum tilt, bow and twist (mm at ``R`` from the datum centre)
``pose_error``   ``e_p / (N.u)``                  TCS position error along the datum normal, one
                 number per pose (mm; gauge ``sum e_p = 0``)
``outliers``     ``g_j`` on flagged readings      gross readings (mm), equivalent to dropping them

A constant term is absorbed by the zero point along the beam (an exact degeneracy: moving
``E`` by ``delta u`` changes every reading by ``-delta``), so components carry no constant.
The covariates ``gamma``, ``N.u`` and the spot position are evaluated at the base
calibration and held fixed in the extended fit (their dependence on the tilt parameters is
second order: a product of two small numbers); ``d0`` is live.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

__all__ = [
    "Covariates",
    "Component",
    "Scale",
    "Incidence",
    "Drift",
    "Nonlinearity",
    "PlaneForm",
    "PoseError",
    "Outliers",
    "ExtendedModel",
    "CATALOGUE",
    "VERDICTS",
    "SECONDS_PER_HOUR",
    "REFERENCE_TEMP_C",
]

#: names of the catalogued effects (the ``cause`` of a diagnosis) and the two verdicts
CATALOGUE = ("scale", "incidence", "drift", "nonlinearity", "plane_form", "pose_error", "outliers")
VERDICTS = ("none", "unexplained")
SECONDS_PER_HOUR = 3600.0
#: reference temperature of dimensional metrology (ISO 1), deg C
REFERENCE_TEMP_C = 20.0


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
    """

    time_h: np.ndarray
    temp_c: np.ndarray
    cos_inc: np.ndarray
    inv_nu: np.ndarray
    spot_st: np.ndarray
    range_mm: np.ndarray

    @property
    def n_poses(self) -> int:
        return len(self.time_h)

    def select(self, idx) -> "Covariates":
        """The poses ``idx``."""
        return replace(self, time_h=self.time_h[idx], temp_c=self.temp_c[idx], cos_inc=self.cos_inc[idx],
                       inv_nu=self.inv_nu[idx], spot_st=self.spot_st[idx])

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
        return cls(time_h, temp, np.abs(nu), 1.0 / nu, spot_st, np.asarray(range_mm, float))


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
    out = np.zeros_like(cols)
    idx = list(sensors)
    out[:, idx] = cols[:, idx]
    return out


@dataclass(frozen=True)
class Scale(Component):
    """Gain error ``k``: the reading is ``(1 + k) d0`` (a constant part is a zero shift)."""

    name = "scale"
    param_names = ("k",)
    param_units = ("1",)
    uses_d0 = True

    def basis(self, d0, cov):
        return _sensor_basis(d0[..., None], d0.shape[1], self.sensors)

    def d_dd0(self, values, d0, cov):
        return np.where(self._mask(d0.shape[1])[None, :], values[0], 0.0) * np.ones_like(d0)


@dataclass(frozen=True)
class Incidence(Component):
    """Bias ``c tan^2(gamma)``: grows from zero at normal incidence, ``c`` mm at 45 deg.

    A triangulation sensor's spot elongates as ``1/cos(gamma)`` on a tilted surface and the
    centroid of its image shifts with the speckle and intensity gradient across it; the
    manufacturers' curves of error against tilt are even in the angle and grow faster than
    linearly: ``tan^2`` is the lowest-order even form that vanishes at normal incidence.
    """

    name = "incidence"
    param_names = ("c_mm",)
    param_units = ("mm",)

    def basis(self, d0, cov):
        t2 = 1.0 / cov.cos_inc**2 - 1.0
        return _sensor_basis(t2[..., None], d0.shape[1], self.sensors)


@dataclass(frozen=True)
class Drift(Component):
    """Zero drift ``r (T - T_ref)`` with temperature (``variable="temp"``, mm/K) or
    ``r (t - t_ref)`` with time (``variable="time"``, mm/h): warm-up of the sensor and
    thermal growth of its mount.

    ``ref`` is a fixed reference, never the first pose of whatever subset is evaluated (a
    k-fold held-out set would then be shifted by ``r`` times the difference of its first
    temperature and the training set's). The zero points of the extended model are those at
    ``ref``; a constant part is a zero shift, so ``ref`` changes the zero point, not the rate
    or the fit, but it sets how strongly the rate correlates with the zero point (least at
    the run's mean, which the diagnosis uses). Default :data:`REFERENCE_TEMP_C` (20 deg C,
    the reference temperature of dimensional metrology, ISO 1) for temperature, 0 h (the
    run's first pose) for time.
    """

    variable: str = "temp"
    ref: float | None = None

    name = "drift"

    @property
    def param_names(self):
        return ("rate_mm_per_K",) if self.variable == "temp" else ("rate_mm_per_h",)

    @property
    def param_units(self):
        return ("mm/K",) if self.variable == "temp" else ("mm/h",)

    def __post_init__(self):
        if self.variable not in ("temp", "time"):
            raise ValueError(f"drift variable must be 'temp' or 'time', got {self.variable!r}")
        if self.ref is None:
            object.__setattr__(self, "ref", REFERENCE_TEMP_C if self.variable == "temp" else 0.0)
        super().__post_init__()

    @property
    def label(self):
        return super().label + ("@temp" if self.variable == "temp" else "@time")

    def covariate(self, cov):
        """``(p,)``: ``T - ref`` (K) or ``t - ref`` (h) of the poses of ``cov``."""
        x = cov.temp_c if self.variable == "temp" else cov.time_h
        if not np.all(np.isfinite(x)):
            raise ValueError(f"drift with {self.variable}: the export has no {self.variable} column")
        return x - self.ref

    def describe(self):
        out = super().describe()
        out["reference"] = {"value": float(self.ref), "unit": "deg C" if self.variable == "temp" else "h"}
        return out

    def basis(self, d0, cov):
        x = np.broadcast_to(self.covariate(cov)[:, None], d0.shape)
        return _sensor_basis(x[..., None], d0.shape[1], self.sensors)


def _legendre23(x):
    return 0.5 * (3 * x**2 - 1), 0.5 * (5 * x**3 - 3 * x)


@dataclass(frozen=True)
class Nonlinearity(Component):
    """Linearity error ``c2 P2(x) + c3 P3(x)`` over the normalised range ``x`` in [-1, 1].

    The datasheet's linearity error is the deviation from the best straight line over the
    full range, so its constant and linear parts are zero by definition: the first two
    Legendre polynomials orthogonal to them are the bow (``P2``) and the S-shape (``P3``);
    ``c2``, ``c3`` are their values at the end of the range (mm).
    """

    name = "nonlinearity"
    param_names = ("c2_mm", "c3_mm")
    param_units = ("mm", "mm")
    uses_d0 = True

    def _x(self, d0, cov):
        lo, hi = cov.range_mm[:, 0], cov.range_mm[:, 1]
        return (2 * d0 - lo - hi) / (hi - lo), 2.0 / (hi - lo)

    def basis(self, d0, cov):
        x, _ = self._x(d0, cov)
        p2, p3 = _legendre23(x)
        return _sensor_basis(np.stack([p2, p3], axis=-1), d0.shape[1], self.sensors)

    def d_dd0(self, values, d0, cov):
        x, dx = self._x(d0, cov)
        deriv = (values[0] * 3 * x + values[1] * 0.5 * (15 * x**2 - 3)) * dx[None, :]
        return np.where(self._mask(d0.shape[1])[None, :], deriv, 0.0)


@dataclass(frozen=True)
class PlaneForm(Component):
    """Datum form ``w = b_s s + b_t t + b_ss s^2 + b_st s t + b_tt t^2`` (s, t in units of
    ``radius_mm`` from the datum centre, along the plane's axes in the tracker frame).

    The datum's deviation from the plane it was given as, along the plane normal, at the
    spot; the reading changes by ``w / (N.u)``. The quadratic part is the datum's bow,
    saddle and twist; the linear part a tilt of the datum under the spots against the plane
    fitted to the cloud (which the cloud's own extent and the centre's choice leave). A
    constant part is the plane's offset, absorbed by the zero points.
    """

    radius_mm: float = 100.0

    name = "plane_form"
    param_names = ("b_s_mm", "b_t_mm", "b_ss_mm", "b_st_mm", "b_tt_mm")
    param_units = ("mm",) * 5

    def monomials(self, st_mm):
        """``(..., 5)``: ``s, t, s^2, s t, t^2`` at in-plane positions ``st_mm (..., 2)`` mm."""
        s, t = st_mm[..., 0] / self.radius_mm, st_mm[..., 1] / self.radius_mm
        return np.stack([s, t, s * s, s * t, t * t], axis=-1)

    def height(self, st_mm):
        """``w (...)`` mm: the datum's deviation along its normal at ``st_mm (..., 2)`` mm."""
        return self.monomials(st_mm) @ self.values

    def basis(self, d0, cov):
        return self.monomials(cov.spot_st) * cov.inv_nu[..., None]

    @classmethod
    def from_cloud(cls, points, plane_normal, plane_offset, centre, radius_mm=100.0, names=()):
        """The datum's form measured by the tracker, as a component (values and stderr).

        Least squares of the points' signed distance to the plane on ``1`` and
        :meth:`monomials`, in the axes the readings' component uses
        (:func:`~metrology.simulation.plane_basis` of the normal, from ``centre``): an
        independent measurement of the surface the beams see. Its quadratic part (bow,
        saddle, twist) must agree with a ``plane_form`` fitted to the readings; the constant
        is the plane's offset (dropped), the linear part the cloud's tilt against the plane
        given (zero when that plane was fitted to this cloud).

        Parameters
        ----------
        points : (m, 3) float, mm, tracker frame, m >= 7
        plane_normal : (3,) float, unit, tracker frame; plane_offset : float, mm
        centre : (3,) float, mm, tracker frame (as in :func:`metrology.diagnosis.covariates_for`)
        radius_mm : float, the unit of ``s, t``

        Returns
        -------
        form : PlaneForm, values with stderr
        cov : (5, 5) float, covariance of the values, ``s^2 (A^T A)^-1`` with ``s`` the
            residual scatter (which also takes up any form beyond quadratic)
        """
        from metrology.core.plane import plane_basis

        P = np.asarray(points, float)
        if P.ndim != 2 or P.shape[1] != 3 or len(P) < 7:
            raise ValueError(f"datum cloud: need (m >= 7, 3) points, got shape {P.shape}")
        n = np.asarray(plane_normal, float)
        w = P @ n + float(plane_offset)
        form = cls((), names=tuple(names), radius_mm=radius_mm)
        A = np.concatenate([np.ones((len(P), 1)), form.monomials((P - np.asarray(centre, float)) @ plane_basis(n).T)],
                           axis=1)
        coef, *_ = np.linalg.lstsq(A, w, rcond=None)
        r = w - A @ coef
        C = np.linalg.pinv(A.T @ A) * (float(r @ r) / max(len(w) - 6, 1))
        C5 = C[1:, 1:]
        return form.with_values(coef[1:], np.sqrt(np.maximum(np.diag(C5), 0.0))), C5


@dataclass(frozen=True)
class PoseError(Component):
    """Per-pose TCS position error ``e_p`` along the datum normal (tracker, robot settling):
    the reading of every sensor of pose ``p`` changes by ``e_p / (N.u)``, a common mode.
    ``n_poses`` parameters with the gauge ``sum_p e_p N_p = 0`` (``N_p`` the plane normal in the
    TCS of pose ``p``): moving every zero point by ``v`` is exactly the per-pose error
    ``-N_p . v``. The diagnosis profiles the values out of its fit (variable projection, with
    that gauge); the row of :meth:`constraint` (``sum e_p = 0``) serves a direct joint fit."""

    n_poses: int = 0

    name = "pose_error"
    per_pose = True
    #: weight of the gauge row (per mm of sum), large against 1/sigma
    GAUGE_WEIGHT = 1e4

    @property
    def param_names(self):
        return tuple(f"e{j}_mm" for j in range(self.n_poses))

    @property
    def param_units(self):
        return ("mm",) * self.n_poses

    def select(self, idx):
        k = len(np.arange(self.n_poses)[idx])
        return replace(self, n_poses=k, values=np.asarray(self.values)[idx], stderr=None)

    def basis(self, d0, cov):
        p, n = d0.shape
        B = np.zeros((p, n, p))
        B[np.arange(p), :, np.arange(p)] = cov.inv_nu
        return B

    def constraint(self, values):
        return np.array([self.GAUGE_WEIGHT * np.sum(values)]), np.full((1, self.n_poses), self.GAUGE_WEIGHT)

    def describe(self):
        out = super().describe()
        v = self.values
        out["params"] = {"sigma_mm": {"value": float(np.std(v, ddof=1)) if len(v) > 1 else 0.0, "unit": "mm",
                                      "stderr": None}}
        return out


@dataclass(frozen=True)
class Outliers(Component):
    """Gross readings: one free term ``g_j`` (mm) per flagged reading, which is the same as
    leaving the reading out. ``flags`` is the ``(p, n)`` boolean mask of flagged readings."""

    flags: np.ndarray = field(default_factory=lambda: np.zeros((0, 0), bool))

    name = "outliers"

    @property
    def cells(self):
        return np.argwhere(self.flags)

    @property
    def param_names(self):
        return tuple(f"g_p{p}_{self.names[i] if self.names else i}_mm" for p, i in self.cells)

    @property
    def param_units(self):
        return ("mm",) * len(self.cells)

    def select(self, idx):
        return replace(self, flags=self.flags[idx], values=None, stderr=None)

    def basis(self, d0, cov):
        p, n = d0.shape
        cells = self.cells
        B = np.zeros((p, n, len(cells)))
        B[cells[:, 0], cells[:, 1], np.arange(len(cells))] = 1.0
        return B


@dataclass(frozen=True)
class ExtendedModel:
    """The base geometry plus a list of components.

    Attributes
    ----------
    layout : SensorLayout, the sensors' zero points and directions (TCS)
    components : tuple of Component
    """

    layout: object
    components: tuple = ()

    def __post_init__(self):
        seen = set()
        for c in self.components:
            for pn in c.full_param_names:
                if pn in seen:
                    raise ValueError(f"parameter name clash: {pn} appears in two components")
                seen.add(pn)
        object.__setattr__(self, "components", tuple(self.components))

    @property
    def param_names(self) -> tuple:
        return tuple(pn for c in self.components for pn in c.full_param_names)

    def terms(self, d0, cov: Covariates):
        """``(p, n)`` mm: the sum of the components' terms."""
        out = np.zeros_like(d0)
        for c in self.components:
            out = out + c.evaluate(c.values, d0, cov)
        return out

    def predict(self, normal_tcs, offset_tcs, cov: Covariates):
        """Readings ``(p, n)`` mm of the extended model on planes ``(p, 3)``, ``(p,)`` in the TCS."""
        from metrology.core.model import readings

        d0, _ = readings(self.layout.zero, self.layout.direction, normal_tcs, offset_tcs)
        return d0 + self.terms(d0, cov)
