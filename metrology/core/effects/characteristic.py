"""Effects on one sensor's characteristic, its reading as a function of the distance along its beam: gain
(:class:`Scale`) and linearity (:class:`Nonlinearity`: Legendre polynomials or a cubic spline over the readings'
span) (registry entries, the family "characteristic")."""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from metrology.core.effects.base import Component, _sensor_basis

__all__ = ["Scale", "Nonlinearity", "legendre23"]


def _characteristic_rows(comp, cov):
    """The term of a characteristic (gain, curve) along its sensor's readings: ``(B (201, k),
    meaning)`` over the span of the readings it gave (beyond them the data say nothing of the
    curve; the stated range without a span)."""
    i = comp.sensors[0]
    lo, hi = cov.d_span[i] if cov.d_span is not None else cov.range_mm[i]
    grid = np.linspace(lo, hi, 201)
    d_grid = np.zeros((len(grid), len(cov.range_mm)))
    d_grid[:, i] = grid
    return comp.basis(d_grid, cov)[:, i, :], "peak-to-valley of the characteristic over the readings' span"


@dataclass(frozen=True)
class Scale(Component):
    """Gain error ``k``: the reading is ``(1 + k) d0`` (a constant part is a zero shift)."""

    name = "scale"
    param_names = ("k",)
    param_units = ("1",)
    uses_d0 = True
    advice = "readings over the whole measuring range (a wider spread of stand-off)"
    size_meaning = "gain error k (unitless)"
    plot_key = "d_mm"
    family = "characteristic"
    confused_with = ("crosstalk",)
    detectable_meaning = "peak-to-valley of a gain error over the readings' span, told from crosstalk"

    def size_rows(self, d0, cov):
        return _characteristic_rows(self, cov)

    def detectable_direction(self):
        return np.ones(1)

    def basis(self, d0, cov):
        return _sensor_basis(d0[..., None], d0.shape[1], self.sensors)

    def d_dd0(self, values, d0, cov):
        return np.where(self._mask(d0.shape[1])[None, :], values[0], 0.0) * np.ones_like(d0)


@functools.lru_cache(maxsize=16)
def _legendre_derivatives(order):
    """``(order, order + 1)``, read-only: column ``j`` the coefficients of ``P_j'`` in ``P0 .. P_order-1``."""
    D = np.polynomial.legendre.legder(np.eye(order + 1), axis=0)
    D.flags.writeable = False
    return D


@functools.lru_cache(maxsize=256)
def _spline_setup(a, b, n_inner, inner=None):
    """Knots of the cubic spline on ``[a, b]`` with ``n_inner`` even interior knots (or those of
    ``inner``, a tuple in the same units), and each basis function's least-squares line there:
    ``(t, (a0 (nb,), a1 (nb,)), a1)`` (cached, bounded: knots at the readings' quantiles differ
    with every data set)."""
    from scipy.interpolate import BSpline

    inner = np.linspace(a, b, n_inner + 2)[1:-1] if inner is None else np.asarray(inner, float)
    t = np.concatenate([[a] * 4, inner, [b] * 4])
    g = np.linspace(a, b, 201)
    G = BSpline.design_matrix(g, t, 3).toarray()
    A = np.stack([np.ones_like(g), g], axis=1)
    coef = np.linalg.lstsq(A, G, rcond=None)[0]  # (2, nb)
    return t, (coef[0], coef[1]), coef[1]


@functools.lru_cache(maxsize=256)
def _spline_derivatives(a, b, n_inner, inner=None):
    """The derivative of each cubic B-spline of :func:`_spline_setup`'s knots (same key), built
    once per knot set (cached, bounded)."""
    from scipy.interpolate import BSpline

    t = _spline_setup(a, b, n_inner, inner)[0]
    nb = len(t) - 4
    return tuple(BSpline(t, np.eye(nb)[j], 3, extrapolate=True).derivative() for j in range(nb))


def legendre23(x):
    """``(P2(x), P3(x))``: the bow and S-shape of a reading normalised to ``x`` in [-1, 1]."""
    return 0.5 * (3 * x**2 - 1), 0.5 * (5 * x**3 - 3 * x)


@dataclass(frozen=True)
class Nonlinearity(Component):
    """Linearity error ``c2 P2(x) + c3 P3(x)`` over the normalised range ``x`` in [-1, 1].

    The datasheet's linearity error is the deviation from the best straight line over the
    full range, so its constant and linear parts are zero by definition: the first two
    Legendre polynomials orthogonal to them are the bow (``P2``) and the S-shape (``P3``);
    ``c2``, ``c3`` are their values at the end of the range (mm).

    ``with_gain=True`` adds the gain ``k d0`` (the linear part, as :class:`Scale`): the sensor's
    whole characteristic to third order. The diagnosis scores this family member beside
    ``scale`` and names ``nonlinearity`` only when the curve predicts held-out poses
    significantly better than the gain alone (a real characteristic, e.g. an S-curve that
    flattens at one end, has both parts).

    ``order`` (3 or 5) is the highest Legendre polynomial: ``order=5`` adds ``c4 P4 + c5 P5``
    for a characteristic with more turns (a calibration table with several knots). ``order=0``
    is a cubic regression spline instead (``knots`` interior knots, :data:`SPLINE_KNOTS` by
    default, evenly over ``span`` (the readings the sensor gave; default the range), its
    constant and linear parts removed there): any smooth curve with a few turns,
    ``s1..s{knots + 2}`` mm. ``inner_mm`` (a tuple of ``knots`` increasing readings, mm,
    inside ``span``), if given, places the interior knots there instead (label ``@spline{k}q``:
    the diagnosis puts them at the readings' quantiles, where readings crowd in part of the
    span). The diagnosis takes a richer member (more knots, ``@spline8``) only when it predicts
    held-out poses significantly better.
    """

    #: interior knots of the spline member (``order=0``), evenly spaced over the range
    SPLINE_KNOTS = 4

    with_gain: bool = False
    order: int = 3
    span: tuple | None = None
    knots: int = SPLINE_KNOTS
    inner_mm: tuple | None = None

    name = "nonlinearity"
    uses_d0 = True
    advice = "readings over the whole measuring range (a wider spread of stand-off)"
    size_meaning = "c3 mm at the range end (c2 = c3/2)"
    plot_key = "d_mm"
    family = "characteristic"
    confused_with = ("crosstalk",)
    detectable_meaning = "peak-to-valley beyond a straight line over the readings' span, the least favourable of P2-P4"
    worst_shape = True
    #: the Legendre orders over which the detectable size is the worst
    SHAPE_ORDERS = (2, 3, 4)
    #: interior knots of the richer splines, tried in turn once a curve is chosen (4: the scored
    #: member's count, with its knots at the readings' quantiles instead)
    SPLINE_LADDER = (4, 8, 12)

    def size_rows(self, d0, cov):
        return _characteristic_rows(self, cov)

    def detectable_direction(self):
        names = list(self.param_names)
        return np.eye(self.n_params)[names.index("c2_mm")] if "c2_mm" in names and self.n_params == 3 else None

    @classmethod
    def detectable_shapes(cls, d0_i, cos_inc_i, fin):
        """The Legendre polynomials of the reading over the span it covered, each of peak-to-valley
        1 once its best straight line there is taken off (as the size is defined)."""
        from numpy.polynomial import legendre

        d = np.where(fin, d0_i, np.nan)
        lo, hi = float(np.nanmin(d)), float(np.nanmax(d))
        if not hi > lo:
            return []
        out = []
        grid = np.linspace(-1.0, 1.0, 401)
        for k in cls.SHAPE_ORDERS:
            c = np.eye(k + 1)[k]
            g = legendre.legval(grid, c)
            g = g - np.polyval(np.polyfit(grid, g, 1), grid)
            out.append(legendre.legval((2 * d - lo - hi) / (hi - lo), c) / float(g.max() - g.min()))
        return out

    def richer(self, k, d, span):
        """The rung of ``k`` interior knots of the spline ladder on this member's sensor: the
        spline with knots evenly over ``span`` (mm, the readings' span, or None: the range), and
        with knots at the quantiles of the readings ``d`` (sorted, finite, mm) where they are far
        enough apart; those not already this member."""
        i = self.sensors[0]
        rung = []
        if not (self.order == 0 and k <= self.knots) and k != self.SPLINE_KNOTS:
            rung.append(Nonlinearity((i,), names=self.names, with_gain=True, order=0, span=span, knots=k))
        inner = tuple(float(v) for v in np.quantile(d, np.arange(1, k + 1) / (k + 1)))
        # knots apart by at least a thousandth of the span (quantised or repeated readings can put
        # two quantiles on one value, and a basis function between them has no support)
        if len(d) >= 2 * (k + 4) and np.all(np.diff((d[0],) + inner + (d[-1],)) > 1e-3 * (d[-1] - d[0])):
            rung.append(Nonlinearity((i,), names=self.names, with_gain=True, order=0, span=span, knots=k,
                                     inner_mm=inner))
        return rung

    @classmethod
    def hidden(cls, i, size):
        return cls((i,), [0.5 * size, size])

    @classmethod
    def candidates_for_sensor(cls, i, names, cov):
        return [cls((i,), names=names, with_gain=True), cls((i,), names=names, with_gain=True, order=5),
                cls((i,), names=names, with_gain=True, order=0,
                    span=None if cov.d_span is None else tuple(float(v) for v in cov.d_span[i]))]

    def __post_init__(self):
        if self.order not in (0, 3, 5):
            raise ValueError(f"nonlinearity order must be 3, 5 or 0 (spline), got {self.order}")
        if self.order == 0 and not 1 <= self.knots <= 32:
            raise ValueError(f"nonlinearity spline knots must be 1..32, got {self.knots}")
        if self.inner_mm is not None:
            lo, hi = self.span if self.span is not None else (-np.inf, np.inf)
            k = np.asarray(self.inner_mm, float)
            if (self.order != 0 or len(k) != self.knots or np.any(np.diff(k) <= 0)
                    or not (np.all(k > lo) and np.all(k < hi))):
                raise ValueError(f"nonlinearity inner_mm must be {self.knots} increasing knots of a spline "
                                 f"(order 0) inside its span {self.span}, got {self.inner_mm} at order {self.order}")
        super().__post_init__()

    @property
    def _n_shape(self):
        return self.knots + 2 if self.order == 0 else self.order - 1

    @property
    def param_names(self):
        shape = (tuple(f"s{j}_mm" for j in range(1, self._n_shape + 1)) if self.order == 0
                 else tuple(f"c{j}_mm" for j in range(2, self.order + 1)))
        return (("k",) if self.with_gain else ()) + shape

    @property
    def param_units(self):
        return (("1",) if self.with_gain else ()) + ("mm",) * self._n_shape

    @property
    def label(self):
        spline = ("@spline" + ("" if self.knots == self.SPLINE_KNOTS and self.inner_mm is None else str(self.knots))
                  + ("q" if self.inner_mm is not None else ""))
        return super().label + {0: spline, 3: "", 5: "@5"}[self.order]

    def _spline(self, x, a=-1.0, b=1.0, inner=None, deriv=True, value=True):
        """``(..., n, knots + 2)``: cubic B-splines on ``[a, b]`` (normalised; interior knots ``inner`` or even) less
        their least-squares line there (NaN if not ``value``), and their derivatives in ``x`` (NaN if not
        ``deriv``), on its sensors."""
        from scipy.interpolate import BSpline

        t, line, dline = _spline_setup(float(a), float(b), self.knots, inner)
        xf = np.asarray(x, float).ravel()
        # a reading the model cannot place (NaN) has no basis value, nor has another sensor's (its term is zero)
        ok = np.isfinite(xf) & np.broadcast_to(self._mask(np.shape(x)[-1]), np.shape(x)).ravel()
        nb = len(t) - 4
        B = np.full((len(xf), nb), np.nan)
        dB = np.full((len(xf), nb), np.nan)
        if value and np.any(ok):
            B[ok] = BSpline.design_matrix(xf[ok], t, 3, extrapolate=True).toarray()
        for j, dspline in enumerate(_spline_derivatives(float(a), float(b), self.knots, inner) if deriv else ()):
            dB[ok, j] = dspline(xf[ok])  # derivative of each basis function (nb small)
        P = B - line[0][None, :] - xf[:, None] * line[1][None, :]
        dP = dB - dline[None, :]
        shape = np.shape(x) + (nb - 2,)
        # nb - 2 independent columns remain after removing the line: drop the first and last
        return P[:, 1:-1].reshape(shape), dP[:, 1:-1].reshape(shape)

    def _legendre(self, x, cov, deriv=True, value=True):
        """``(..., order - 1)``: ``P2(x) .. P_order(x)``, and their derivatives in ``x`` (the
        spline's columns for ``order=0``; none if not ``deriv``, with Legendre columns; the
        values NaN (spline) or None (Legendre) if not ``value``: the derivative alone skips its
        design matrix or Vandermonde matrix)."""
        from numpy.polynomial import legendre

        if self.order == 0:
            inner = None
            if self.inner_mm is not None:
                lo, hi = cov.range_mm[self.sensors[0]]
                inner = tuple(float((2 * k - lo - hi) / (hi - lo)) for k in self.inner_mm)
            return self._spline(x, *self._span_x(cov), inner, deriv, value)
        # (..., order + 1): P0 .. P_order; not made when only the derivatives are asked for (d_dd0)
        V = legendre.legvander(x, self.order)[..., 2:] if value else None
        if not deriv:
            return V, None
        dV = legendre.legvander(x, self.order - 1) @ _legendre_derivatives(self.order)
        return V, dV[..., 2:]

    def _x(self, d0, cov):
        lo, hi = cov.range_mm[:, 0], cov.range_mm[:, 1]
        return (2 * d0 - lo - hi) / (hi - lo), 2.0 / (hi - lo)

    def _span_x(self, cov):
        """The spline's interval ``(a, b)`` in normalised units: ``span`` (default the range)."""
        if not self.sensors:
            return -1.0, 1.0
        i = self.sensors[0]
        lo, hi = cov.range_mm[i]
        a, b = self.span if self.span is not None else (lo, hi)
        return (2 * a - lo - hi) / (hi - lo), (2 * b - lo - hi) / (hi - lo)

    def basis(self, d0, cov):
        x, _ = self._x(d0, cov)
        P, _ = self._legendre(x, cov, deriv=False)
        cols = np.concatenate([d0[..., None], P], axis=-1) if self.with_gain else P
        return _sensor_basis(cols, d0.shape[1], self.sensors)

    def d_dd0(self, values, d0, cov):
        x, dx = self._x(d0, cov)
        g = values[0] if self.with_gain else 0.0
        _, dP = self._legendre(x, cov, value=False)
        deriv = g + (dP @ np.asarray(values[-self._n_shape:], float)) * dx[None, :]
        return np.where(self._mask(d0.shape[1])[None, :], deriv, 0.0)
