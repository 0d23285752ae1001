"""What :func:`metrology.measure.surface.fit_surface`'s second-order local surface leaves out, from the
CAD: the panel's height beyond second order at the spots (:func:`second_order_readings`) and the
head's spin about the tool axis at its measured axis in the cell's convention (:func:`convention_spin`).
Both are applied by :func:`metrology.measure.surface.surface_hole_normals` before its fit (one more
fit of the readings), where :class:`metrology.measure.surface.PanelTerms` carries them.

Measured (benchmarks/results/measure_ring_seed13.md): a 3-sensor ring of footprint 43 mm on the
nacelle lip and the saddle, noise-free and its layout exact, leaves 0.003 deg rms without them (a
quarter of its U95), 1e-4 deg with them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from metrology.measure.normals import drill_axis

__all__ = ["second_order_readings", "convention_spin", "beyond_second_order", "Beyond"]


@dataclass(frozen=True)
class Beyond:
    """What the CAD and the pose give beyond the second-order surface, per hole (:func:`beyond_second_order`).

    Attributes
    ----------
    axes : (h, 2, 3) float, unit, TCS, the local axes ``e1, e2`` of ``higher``
    higher : (h, 9) float, the CAD's height beyond second order (:class:`metrology.measure.panel.HoleSurfaces`)
    tcs2panel : (h, 3, 3) float or None, the head's rotation the shape was put into the TCS with
    turn : (h, 3, 3) float or None, the turn about the axis found before the adjustment (NaN rows: none)
    """

    axes: np.ndarray
    higher: np.ndarray
    tcs2panel: np.ndarray | None = None
    turn: np.ndarray | None = None

    def rows(self, r):
        """The holes ``r`` (an index)."""
        return Beyond(*(None if x is None else x[r] for x in (self.axes, self.higher, self.tcs2panel, self.turn)))


def beyond_second_order(layout, d, shape, terms: Beyond, fit0):
    """``(d, shape, turn)``: the readings and the shape square to the axis that the second-order fit
    should take, and the turn about the axis applied (``(N, 3, 3)``), from a first fit ``fit0`` of
    ``d (N, n)`` mm with ``shape (N, 3, 3)`` 1/mm TCS and ``terms`` (:class:`Beyond`):

    - ``terms.tcs2panel (N, 3, 3)``: the head's rotation the shape (and ``axes``) were put into the
      TCS with (the commanded pose, or the cell's convention at the CAD's normal; columns the TCS axes
      in the panel frame): the head's spin at its measured axis in the cell's convention
      (:func:`convention_spin`); or ``terms.turn (N, 3, 3)`` that turn given (the head after the
      cell's adjustment is the head before it turned by the smallest rotation in the TCS: it keeps the
      spin found before; NaN rows: none);
    - ``terms.axes (N, 2, 3)`` unit TCS, ``terms.higher (N, 9)``: the CAD's height beyond second order
      (:class:`metrology.measure.panel.HoleSurfaces`; :func:`second_order_readings`).
    """
    N = len(d)
    Y = np.broadcast_to(np.eye(3), (N, 3, 3)).copy()
    axes = terms.axes
    if terms.turn is not None:
        given = np.all(np.isfinite(terms.turn), axis=(1, 2))
        Y[given] = terms.turn[given]
    elif terms.tcs2panel is not None:  # the head's spin at its measured axis, in the cell's convention
        ok0 = fit0.ok & np.all(np.isfinite(terms.tcs2panel), axis=(1, 2))
        Y[ok0] = convention_spin(terms.tcs2panel[ok0], fit0.normal[ok0], drill_axis(layout)[2])
    shape = np.swapaxes(Y, 1, 2) @ np.asarray(shape, float) @ Y
    if axes is not None:
        axes = np.einsum("hji,hkj->hki", Y, axes)  # Y^T a
    if terms.higher is not None:
        d = second_order_readings(layout, d, fit0, axes, terms.higher)
    return d, shape, Y
def _smallest(v, w):
    """Smallest rotations ``(h, 3, 3)`` taking unit ``v (h, 3)`` to unit ``w (h, 3)`` (Rodrigues; not opposite)."""
    k = np.cross(v, w)
    c = (v * w).sum(1)
    Kx = np.zeros((len(v), 3, 3))
    Kx[:, 0, 1], Kx[:, 0, 2], Kx[:, 1, 2] = -k[:, 2], k[:, 1], -k[:, 0]
    Kx[:, 1, 0], Kx[:, 2, 0], Kx[:, 2, 1] = k[:, 2], -k[:, 1], k[:, 0]
    return np.eye(3)[None] + Kx + Kx @ Kx / (1.0 + c)[:, None, None]


def convention_spin(tcs2panel, m, s: float):
    """``Y (h, 3, 3)``: the turn about the drill axis that puts the head's spin where the cell's
    convention has it at the head's measured axis.

    The fit turns the shape, given square to the axis under ``tcs2panel`` (``R_c``), onto the measured
    normal ``m`` (TCS, toward the head) by the smallest rotation ``Q_m`` (``sigma e_z -> m``): the head
    ``R = R_c Q_m^T``. The cell holds the commanded spin ``psi_c`` in its convention (metrology/sim/forward/log.py
    step 3; :func:`metrology.measure.panel.tcs2panel_nominal`): at the axis ``a = R s e_z`` its head is
    ``Q(-e_z -> a) F Rz(psi_c)``, not ``R``. The two differ by a spin about the axis, the holonomy of the
    tilt: ``theta beta / 2`` or so for a tilt ``theta`` off an axis ``beta`` from the panel's ``z``
    (0.3 deg at 5 and 7.6 deg, the nacelle's table), which turns a shape of unequal curvatures (a
    saddle: ``2 delta_psi / R``). ``Y = Q_m^T X Q_m`` with ``X = R^T Q(-e_z -> a) F Rz(psi_c)``; the
    shape square to the axis becomes ``Y^T K Y``.

    ``tcs2panel (h, 3, 3)``, ``m (h, 3)`` unit TCS, ``s`` the drill axis's sign."""
    Rc = np.asarray(tcs2panel, float)
    sg = -s
    ez = np.broadcast_to(np.array([0.0, 0.0, sg]), m.shape)
    Qm = _smallest(ez, m)
    R = Rc @ np.swapaxes(Qm, 1, 2)
    a = R[:, :, 2] * s
    f = Rc[:, :, 2] * s
    flip = np.array([1.0, -s, -s])  # F (columns)
    down = np.broadcast_to(np.array([0.0, 0.0, -1.0]), m.shape)
    spin_c = np.swapaxes(_smallest(down, f) * flip, 1, 2) @ Rc  # F Q(-e_z -> f)^T R_c = Rz(psi_c)
    X = np.swapaxes(R, 1, 2) @ (_smallest(down, a) * flip) @ spin_c
    return np.swapaxes(Qm, 1, 2) @ X @ Qm


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
    d = np.asarray(d, float)
    m = np.where(fit.ok[:, None], fit.normal, np.array([0.0, 0.0, 1.0]))
    m0, m1, m2 = (m[:, k:k + 1] for k in range(3))  # (h, 1): the products below by component, over (h, n)
    z, u = layout.zero, layout.direction
    qx, qy = z[:, 0] + d * u[:, 0], z[:, 1] + d * u[:, 1]  # q = S - c e_z, S = E + d u
    qz = z[:, 2] + d * u[:, 2] - np.where(fit.ok, fit.c, 0.0)[:, None]
    a = np.asarray(axes, float)
    a = a - (a * m[:, None]).sum(2)[..., None] * m[:, None]
    a /= np.linalg.norm(a, axis=2, keepdims=True)
    a = np.ascontiguousarray(np.moveaxis(a, 0, 2))[..., None]  # (2, 3, h, 1)
    # (s, t): T q along the axes; the axes are square to m, so T q . a = q . a
    s_ = qx * a[0, 0] + qy * a[0, 1] + qz * a[0, 2]
    t_ = qx * a[1, 0] + qy * a[1, 1] + qz * a[1, 2]
    # the nine terms with the products shared, each coefficient a contiguous column (no ``**``)
    c = np.ascontiguousarray((np.asarray(higher, float) / _TAYLOR).T)[:, :, None]  # (9, h, 1)
    s2, st, t2 = s_ * s_, s_ * t_, t_ * t_
    w = (s_ * (c[0] * s2 + c[1] * st + c[2] * t2) + c[3] * t_ * t2
         + s2 * (c[4] * s2 + c[5] * st + c[6] * t2) + t2 * (c[7] * st + c[8] * t2))
    um = np.abs(u[:, 0] * m0 + u[:, 1] * m1 + u[:, 2] * m2)
    out = d + w / um
    return np.where(fit.ok[:, None] & np.isfinite(out), out, d)

