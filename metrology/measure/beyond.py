"""What :func:`metrology.measure.surface.fit_surface`'s second-order local surface leaves out, from the
CAD: the panel's height beyond second order at the spots (:func:`second_order_readings`) and the
head's spin about the tool axis at its measured axis in the cell's convention
(:func:`metrology.measure.commanded.commanded_turn`).
Both are applied by :func:`metrology.measure.surface.surface_hole_normals` before its fit (one more
fit of the readings), where :class:`metrology.measure.surface.PanelTerms` carries them.

Measured (benchmarks/results/measure_ring_seed13.md): a 3-sensor ring of footprint 43 mm on the
nacelle lip and the saddle, noise-free and its layout exact, leaves 0.003 deg rms without them (a
quarter of its U95), 1e-4 deg with them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from metrology.measure.commanded import cad_normal_tcs, commanded_turn
from metrology.measure.normals import drill_axis

__all__ = ["second_order_readings", "beyond_second_order", "Beyond"]


@dataclass(frozen=True)
class Beyond:
    """What the CAD and the pose give beyond the second-order surface, per hole (:func:`beyond_second_order`).

    Attributes
    ----------
    axes : (h, 2, 3) float, unit, TCS, the local axes ``e1, e2`` of ``higher``
    higher : (h, 9) float, the CAD's height beyond second order (:class:`metrology.measure.panel.HoleSurfaces`);
        (h, 9 + E) with degrees 5.. where the footprint needs them (:mod:`metrology.panel.footprint`)
    tcs2panel : (h, 3, 3) float or None, the head's rotation the shape was put into the TCS with
    turn : (h, 3, 3) float or None, the turn about the axis found before the adjustment (NaN rows: none)
    u_height : (h,) float or None, mm, the height at each spot that no term carries (the remainder's fit
        residual: :mod:`metrology.measure.remainder` makes it a term of U95)
    """

    axes: np.ndarray
    higher: np.ndarray
    tcs2panel: np.ndarray | None = None
    turn: np.ndarray | None = None
    u_height: np.ndarray | None = None

    def rows(self, r):
        """The holes ``r`` (an index)."""
        return Beyond(*(None if x is None else x[r]
                        for x in (self.axes, self.higher, self.tcs2panel, self.turn, self.u_height)))


def beyond_second_order(layout, d, shape, terms: Beyond, fit0, refit=None):
    """``(d, shape, turn)``: the readings and the shape square to the axis that the second-order fit
    should take, and the turn about the axis applied (``(N, 3, 3)``), from a first fit ``fit0`` of
    ``d (N, n)`` mm with ``shape (N, 3, 3)`` 1/mm TCS and ``terms`` (:class:`Beyond`):

    - ``terms.tcs2panel (N, 3, 3)``: the head's rotation the shape (and ``axes``) were put into the
      TCS with (the commanded pose, or the cell's convention at the CAD's normal; columns the TCS axes
      in the panel frame): the head's spin at its measured axis in the cell's convention
      (:func:`metrology.measure.commanded.commanded_turn`); or ``terms.turn (N, 3, 3)`` that turn given (the head after the
      cell's adjustment is the head before it turned by the smallest rotation in the TCS: it keeps the
      spin found before; NaN rows: none);
    - ``terms.axes (N, 2, 3)`` unit TCS, ``terms.higher (N, 9)``: the CAD's height beyond second order
      (:class:`metrology.measure.panel.HoleSurfaces`; :func:`second_order_readings`).

    The shape returned is the tangent entries ``(00, 01, 11)`` ((N,) arrays) of ``Y^T K Y``: the
    entries :func:`metrology.measure.surface.fit_surface` takes of a shape square to the axis (``K``'s
    own, ``shape[:, 0, 0], [:, 0, 1], [:, 1, 1]``, likewise). Explicit 3 x 3 products over the holes,
    one ``(N,)`` array per entry (no batched matmul or einsum of 3 x 3 matrices).

    ``refit(d, shape) -> SurfaceFit`` (optional): where ``higher`` carries degrees beyond the quartic (a footprint
    large against the radius, :mod:`metrology.panel.footprint`), the readings are moved once more from a fit of the
    moved ones: the spots' place in the tangent plane and the tilted frame come from ``fit0``, whose tilt is off by
    the quartic's remainder (0.05-0.1 deg at R 50), and the terms' slope there (``t^3 / 2 R^3``) times the spots'
    height (6 mm) turns that into 0.5 um; from the second fit it is of the square of that.
    """
    N = len(d)
    y = None  # Y's entries y[i][j], (N,) arrays
    if terms.turn is not None:
        Y = np.where(_finite_rows(terms.turn)[:, None, None], terms.turn, np.eye(3))
        Yt = np.ascontiguousarray(Y.reshape(N, 9).T)  # (9, N): each entry contiguous, read more than once
        y = [[Yt[3 * i + j] for j in range(3)] for i in range(3)]
    elif terms.tcs2panel is not None:  # the head's spin at its measured axis, in the cell's convention
        Rc = terms.tcs2panel
        ok0 = fit0.ok & _finite_rows(Rc)
        m = fit0.normal
        with np.errstate(invalid="ignore", divide="ignore"):  # a pose off the CAD's normal: metrology.measure.commanded
            sa = drill_axis(layout)[2]
            e = commanded_turn([[Rc[:, i, j] for j in range(3)] for i in range(3)], (m[:, 0], m[:, 1], m[:, 2]),
                               cad_normal_tcs(terms.axes, sa), sa)
        y = [[np.where(ok0, e[i][j], float(i == j)) for j in range(3)] for i in range(3)]
        Y = np.empty((N, 3, 3))
        for i in range(3):
            for j in range(3):
                Y[:, i, j] = y[i][j]
    K = np.asarray(shape, float)
    k00, k01, k11 = K[:, 0, 0], K[:, 0, 1], K[:, 1, 1]
    axes = terms.axes
    if y is None:
        Y = np.broadcast_to(np.eye(3), (N, 3, 3))
        kt = (k00, k01, k11)
        ax = None if axes is None else [[axes[:, k, i] for i in range(3)] for k in range(2)]
    else:
        y00, y01, y10, y11 = y[0][0], y[0][1], y[1][0], y[1][1]
        # (Y^T K Y)_ij over the tangent entries of K (square to the axis: its z row and column are 0)
        a0, a1 = k00 * y00 + k01 * y10, k01 * y00 + k11 * y10  # (K Y)_k0
        b0, b1 = k00 * y01 + k01 * y11, k01 * y01 + k11 * y11  # (K Y)_k1
        kt = (y00 * a0 + y10 * a1, y00 * b0 + y10 * b1, y01 * b0 + y11 * b1)
        if axes is not None:  # Y^T a, each axis's components contiguous
            at = np.ascontiguousarray(np.asarray(axes, float).reshape(N, 6).T)
            ax = [[y[0][i] * at[3 * k] + y[1][i] * at[3 * k + 1] + y[2][i] * at[3 * k + 2] for i in range(3)]
                  for k in range(2)]
        else:
            ax = None
    if terms.higher is not None:
        moved = _readings_beyond(layout, d, fit0, ax, terms.higher, kt if terms.higher.shape[1] > 9 else None)
        if refit is not None and terms.higher.shape[1] > 9:
            return beyond_second_order(layout, d, shape, terms, refit(moved, kt))
        d = moved
    return d, kt, Y


def _finite_rows(X):
    """(h,) bool: every entry of each row of ``X (h, ...)`` finite (their sum by a matrix-vector product:
    NaN and inf carry through it; an inner-axis ``all`` over 9 entries costs six times as much)."""
    X = np.asarray(X, float)
    X = X.reshape(len(X), int(np.prod(X.shape[1:])))  # (h, k), also h = 0
    with np.errstate(invalid="ignore", over="ignore"):
        return np.isfinite(X @ np.ones(X.shape[1]))


#: the Taylor factors of ``higher``'s nine terms (:func:`second_order_readings`)
_TAYLOR = np.array([6.0, 2.0, 2.0, 6.0, 24.0, 6.0, 4.0, 6.0, 24.0])


def second_order_readings(layout, d, fit, axes, higher):
    """The readings the second-order surface of :func:`fit_surface` would give: ``d`` plus the CAD
    surface's height beyond second order at each spot over ``|u_i . m|``.

    The fit models the panel to second order about the drill point; its cubic and quartic terms
    (a curvature that changes across the footprint, a sphere's ``r^4 / 8 R^3``) are heights of up to
    a few um at a 40-60 mm footprint, the order of the reading noise, and they tilt the fit. The
    CAD knows them: at each spot ``q_i = S_i - c e_z`` (TCS, from the ``fit``), ``(s, t)`` its
    components along ``axes`` square to the fitted normal ``m``, ``w = higher . (s^3/6, s^2 t/2,
    s t^2/2, t^3/6, s^4/24, s^3 t/6, s^2 t^2/4, s t^3/6, t^4/24)`` mm along ``m`` (toward the head):
    the beam, running away from the head, meets the panel ``w / |u_i . m|`` before the second-order
    surface.

    Parameters
    ----------
    layout : SensorLayout: zero (n, 3) mm TCS, direction (n, 3) unit TCS
    d : (h, n) float, mm, readings; fit : metrology.measure.surface.SurfaceFit of them (``normal``, ``c``, ``ok``)
    axes : (h, 2, 3) float, unit, TCS; higher : (h, 9) float (see :class:`Beyond`)

    Returns
    -------
    (h, n) float, mm (``d`` where the fit is not ok)
    """
    a = np.asarray(axes, float)
    return _readings_beyond(layout, d, fit, [[a[:, k, i] for i in range(3)] for k in range(2)], higher)


def _readings_beyond(layout, d, fit, ax, higher, kt=None):
    """:func:`second_order_readings` with the axes by component: ``ax[k][i]`` (h,) the ``i``-th TCS
    component of ``e_(k+1)``. Sensor-major ``(n, h)`` arrays (each hole's numbers a contiguous row's
    entries, as :func:`metrology.measure.surface.fit_surface`); returns the transpose of one: the
    fit's own layout, no copy there."""
    dT = np.ascontiguousarray(np.asarray(d, float).T)  # (n, h)
    ok = fit.ok
    mx, my, mz = (np.where(ok, fit.normal[:, i], e) for i, e in enumerate((0.0, 0.0, 1.0)))
    z, u = layout.zero, layout.direction
    qx, qy = z[:, 0, None] + dT * u[:, 0, None], z[:, 1, None] + dT * u[:, 1, None]  # q = S - c e_z, S = E + d u
    qz = z[:, 2, None] + dT * u[:, 2, None] - np.where(ok, fit.c, 0.0)
    st = []
    for k in range(2):  # (s, t): T q along the axes made square to m and unit; T q . a = q . a
        ax0, ax1, ax2 = ax[k]
        am = ax0 * mx + ax1 * my + ax2 * mz
        ax0, ax1, ax2 = ax0 - am * mx, ax1 - am * my, ax2 - am * mz
        f = 1.0 / np.sqrt(ax0 * ax0 + ax1 * ax1 + ax2 * ax2)
        st.append(qx * (ax0 * f) + qy * (ax1 * f) + qz * (ax2 * f))
    s_, t_ = st
    # the nine terms with the products shared, each coefficient a contiguous row (no ``**``)
    higher = np.asarray(higher, float)
    c = np.divide(higher[:, :9].T, _TAYLOR[:, None], out=np.empty((9, len(ok))))  # (9, h)
    s2, st, t2 = s_ * s_, s_ * t_, t_ * t_
    w = (s_ * (c[0] * s2 + c[1] * st + c[2] * t2) + c[3] * t_ * t2
         + s2 * (c[4] * s2 + c[5] * st + c[6] * t2) + t2 * (c[7] * st + c[8] * t2))
    if higher.shape[1] > 9:  # degrees 5.. over a footprint large against the radius (metrology.panel.footprint)
        w = w + _degrees_beyond(higher[:, 9:], s_, t_)
    um = np.abs(u[:, 0, None] * mx + u[:, 1, None] * my + u[:, 2, None] * mz)
    if kt is not None:  # the second-order surface's slope at the spot (a tight radius): moved along the beam by
        # w / |u.m| the spot also moves across it (by half that on a 30 deg beam), where that surface's height (toward
        # the head) has changed by its slope -K q_t times it: to first order the beam meets it after
        # w / (|u.m| - (K q_t).u_t) (``kt`` the tangent entries (00, 01, 11) square to the axis, K > 0 bending away
        # from the head, as :func:`metrology.measure.surface.fit_surface` takes it: turned onto the fitted plane)
        k00, k01, k11 = kt
        px, py = _square_to_axis(qx, qy, qz, mx, my, mz)  # q_t and u_t turned square to the axis, as K is
        ux, uy = _square_to_axis(u[:, 0, None], u[:, 1, None], u[:, 2, None], mx, my, mz)
        um = um - ((k00 * px + k01 * py) * ux + (k01 * px + k11 * py) * uy)
        a = 0.5 * (k00 * ux * ux + 2.0 * k01 * ux * uy + k11 * uy * uy)  # and its curvature along the beam: the root
        w = w + a * (w / um) ** 2  # of a t^2 - |u.m| t + w = 0 to second order
    out = dT + w / um
    keep = ok & np.isfinite(out)
    return (out if keep.all() else np.where(keep, out, dT)).T


def _degrees_beyond(coef, s_, t_):
    """``sum_j coef_j s^a t^b / (a! b!)`` over the exponents of degrees 5.. (:func:`metrology.panel.footprint.extra_exponents`,
    as many as ``coef (h, E)`` has columns), at ``s_, t_ (n, h)`` mm."""
    import math

    w = np.zeros_like(s_)
    sp, tp = [np.ones_like(s_)], [np.ones_like(t_)]
    j, k = 0, 5
    while j < coef.shape[1]:
        while len(sp) <= k:
            sp.append(sp[-1] * s_)
            tp.append(tp[-1] * t_)
        for b in range(k + 1):
            w += (coef[:, j] / (math.factorial(k - b) * math.factorial(b))) * sp[k - b] * tp[b]
            j += 1
        k += 1
    return w


def _square_to_axis(vx, vy, vz, mx, my, mz):
    """The ``x, y`` parts of ``v``'s component square to the unit ``m`` turned by the smallest rotation taking ``m``
    onto ``sign(m_z) e_z`` (``K_m = Q K Q^T``: ``(K_m v_t) . w_t = (K Q^T v_t) . (Q^T w_t)``); arrays broadcast."""
    vm = vx * mx + vy * my + vz * mz
    vx, vy, vz = vx - vm * mx, vy - vm * my, vz - vm * mz
    sg = np.where(mz < 0, -1.0, 1.0)
    wx, wy, c = sg * my, -sg * mx, sg * mz  # m x (sg e_z), and the cosine
    ax, ay, az = wy * vz, -wx * vz, wx * vy - wy * vx  # w x v
    f = 1.0 / (1.0 + c)
    return vx + ax + f * (wy * az), vy + ay + f * (-wx * az)  # + w x (w x v) / (1 + c), its x, y
