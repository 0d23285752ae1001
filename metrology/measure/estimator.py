"""The one estimator of a hole's tilt, which both fitters use: weighted least squares of the spots' heights,
each spot weighted by the inverse of its height's variance (Gauss-Markov), the panel's local surface known
(the shape operator ``K``) or not (the micro-plane: ``K`` left out).

The spots ``S_i = E_i + d_i u_i`` (mm, TCS) lie on the panel; the model is a graph over the TCS ``xy`` plane,
``h_i(g, c) = z_i - c - g_x x_i - g_y y_i + e_i``, with ``e_i = sigma rho (Tq_i)^T K_m (Tq_i) / 2`` the
curved surface's height at the spot (:mod:`metrology.measure.surface`; 0 for the micro-plane). Each step solves
the model linearised in ``c`` (``dh_i / dc = -G_z,i``, ``G_i = dh_i / dS_i``) for ``(g, c)`` directly:

    minimise  sum_i w_i (y_i - g_x x_i - g_y y_i - G_z,i c)^2,    y_i = z_i + e_i + (G_z,i - 1) c_prev

so a spot's curvature enters only as the terms ``e_i`` and ``G_z,i - 1``, exactly 0 where ``K = 0``: a flat
panel's fit is the micro-plane's to the last bit, whatever the steps (the panel path's U95 on a flat panel *is*
the micro-plane's, tests/measure/test_budget.py checks it with ``==``). The first step is the micro-plane (``K``
left out: from ``c = 0`` it would be read far from the spots); the micro-plane stops there.

**Weights** (Gauss-Markov, the reading noise). A reading error moves spot ``i``'s height by
``(G_i . u_i) delta d_i``: its variance ``sigma_i^2 (G_i . u_i)^2``, taken at the head square to the panel
(``G = e_z``), so ``w_i = 1 / (sigma_i u_z,i)^2``: one weight per sensor, fixed over the steps (the estimator is
linear in the heights, and its map ``A = dg / dh`` the budget propagates is exact). The calibration's share of a
spot's variance (``r_i^T C_ii r_i``, :mod:`metrology.measure.terms`) stays out of the weights, and so does the
tilt's (``G`` at the fit): measured on forward-simulated heads neither lowers the angle's error (with a poor
calibration the calibration term raised it by up to 0.5 %), while a sensor 3x noisier than the others weighed
down lowers it by 24-28 %, coverage kept (benchmarks/results/measure_weights_issue49.md). The paper's Eqs. 18-19
weigh the four corners alike: they stay in :mod:`metrology.core.normals` (``metro normals``, the paper's
reproduction).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from metrology.core.sym3 import inv3, null_vector_cols, turned_tangent

__all__ = ["SurfaceFit", "fit_tilt", "spot_weights", "spot_slopes", "drill_axis", "rows_dot", "PLANE_STEPS"]

#: steps of the micro-plane: one weighted solve (the weights do not depend on the fit)
PLANE_STEPS = 1


_DOT = {2: "ij,ij->j", 3: "ij,ij,ij->j"}


def rows_dot(*arrays):
    """(h,) float: ``(a * b).sum(0)`` (or ``(a * b * c).sum(0)``) of sensor-major ``(n, h)`` arrays (or ``(n, 1)``),
    in one pass and without the product's temporary: the same numbers, each hole's products summed over the
    sensors in their order (a single hole's two columns einsum would take as one contiguous dot, its own
    order of sums: there the product, whose sum is the rows' in order)."""
    if max(a.shape[1] for a in arrays) == 1:
        p = arrays[0] * arrays[1]
        return (p if len(arrays) == 2 else p * arrays[2]).sum(0)
    return np.einsum(_DOT[len(arrays)], *arrays)


def drill_axis(layout) -> np.ndarray:
    """(3,) float, unit, TCS: the TCS ``z`` axis signed the way the beams point (the drill axis)."""
    return np.array([0.0, 0.0, 1.0 if np.mean(layout.direction[:, 2]) > 0 else -1.0])


@dataclass(frozen=True)
class SurfaceFit:
    """The tilt (and the local surface's offset) fitted to the readings.

    Attributes
    ----------
    normal : (h, 3) float, unit, TCS, toward the head (NaN where not ok)
    g : (h, 2) float, the slopes ``(g_x, g_y)``; c : (h,) float, mm, the offset along the TCS z axis
    ok : (h,) bool, 3+ finite readings and a well-posed fit
    plane_normal : (h, 3) float, unit, TCS, toward the head: the micro-plane's (the first step)
    (the rest are None unless ``full``)
    A : (h, 2, n) float, the slopes' change per unit change of each height ``h_i`` (the rows of ``g`` of
        the pose's map; the offset's row is not made)
    G : (h, n, 3) float, ``dh_i / dS_i`` (None for the micro-plane: :func:`spot_slopes`)
    q : (h, n, 3) float, mm, ``S_i - c e_z`` (None for the micro-plane)
    w : (h, n) float, the weights (0 for a blank)
    null : (h, n) float or None, n = 4: the unit vector orthogonal to the Jacobian's columns
    h_res : (h, n) float, mm, the heights' misfit at the solution
    Kt : (h, 3, 3) float, 1/mm, the shape operator turned onto the fitted tangent plane (``K_m``; None for the
        micro-plane)
    spots : (x, y), each (n, h) float, mm, TCS, sensor-major: the spots' coordinates (None unless ``full``)
    """

    normal: np.ndarray
    g: np.ndarray
    c: np.ndarray
    ok: np.ndarray
    plane_normal: np.ndarray | None
    A: np.ndarray | None
    G: np.ndarray | None
    q: np.ndarray | None
    w: np.ndarray | None
    null: np.ndarray | None
    h_res: np.ndarray | None
    Kt: np.ndarray | None
    spots: tuple | None = None


def spot_weights(layout, sigma_mm=None, valid=None):
    """(n, 1) or (n, h) float, 1/mm^2: each spot's weight ``1 / (sigma_i u_z,i)^2`` (module docstring).

    Parameters
    ----------
    layout : SensorLayout, n sensors
    sigma_mm : (n,) float, mm, or None (the layout's ``noise_mm``); an unknown one takes the mean of the known, none
        known (or a 0): every spot weighs the same
    valid : (n, h) bool or None, False for a blank (weight 0)
    """
    n = layout.n
    sig = layout.noise_mm if sigma_mm is None else np.broadcast_to(np.asarray(sigma_mm, float), (n,))
    good = np.isfinite(sig)
    if not good.all():
        sig = np.where(good, sig, np.mean(sig[good]) if good.any() else 0.0)
    v = (sig * layout.direction[:, 2]) ** 2  # mm^2: the reading noise along e_z
    w = (1.0 / v if np.all(v > 0) else np.ones(n))[:, None]
    return w if valid is None else w * valid


def _solve(wx, wy, wz, yt, sums):
    """``(g_x, g_y, c)`` minimising ``sum w (yt - g_x x - g_y y - G_z c)^2`` and the inverse's 6 entries
    (``wx = w x``, ``wy = w y``, ``wz = w G_z``; sums over the sensors, axis 0; ``sums`` the normal matrix's 6
    entries, the sums of ``wx x, wx y, wz x, wy y, wz y, wz G_z``)."""
    i00, i01, i02, i11, i12, i22 = inv3(*sums)
    b0, b1, b2 = rows_dot(wx, yt), rows_dot(wy, yt), rows_dot(wz, yt)
    return (i00 * b0 + i01 * b1 + i02 * b2, i01 * b0 + i11 * b1 + i12 * b2, i02 * b0 + i12 * b1 + i22 * b2,
            (i00, i01, i02, i11, i12, i22))


def fit_tilt(layout, d, shape=None, steps: int = PLANE_STEPS, sigma_mm=None, full: bool = True):
    """The tilt of each hole: the micro-plane (``shape`` None), or the local surface's pose with its shape known.

    Parameters
    ----------
    layout : SensorLayout, n >= 3 sensors: zero (n, 3) mm TCS, direction (n, 3) unit TCS
    d : (h, n) float, mm, readings; NaN for blanks (a hole needs 3)
    shape : None (the micro-plane), or (h, 3, 3) float, 1/mm, TCS, the shape operator at each hole, tangent to
        the TCS ``xy`` plane (the head square to the panel), or its entries ``(00, 01, 11)`` as a tuple of (h,)
        arrays (the only ones the fit takes); turned onto the fitted tangent plane
    steps : int >= 1, the first the micro-plane, the rest with ``K`` (none without a shape)
    sigma_mm : (n,) float, mm, or None: the reading noise the weights take (:func:`spot_weights`)
    full : bool, also the arrays the uncertainty needs (``A``, ``G``, ``q``, ``w``, ``null``, ``h_res``, ``Kt``)

    Returns
    -------
    SurfaceFit

    Sensor-major ``(n, h)`` arrays and explicit 3 x 3 algebra: a sum over the sensors is a sum of contiguous
    rows, in the sensors' order (a hole's bits do not depend on its batch).
    """
    n = layout.n
    d = np.asarray(d, float).reshape(-1, n)
    h = len(d)
    K3 = None
    if shape is not None:
        # square to the drill axis (as given): its entries in the TCS xy plane; K_m = Q K Q^T then has
        # K_m m = 0, so K_m T q = T K_m q = K_m q and (Tq)^T K_m (Tq) = q^T K_m q (no projections per step)
        if isinstance(shape, tuple):
            K3 = tuple(np.broadcast_to(np.asarray(k, float), (h,)) for k in shape)
        else:
            K = np.broadcast_to(np.asarray(shape, float), (h, 3, 3))
            K3 = tuple(np.ascontiguousarray(K[:, i, j]) for i, j in ((0, 0), (0, 1), (1, 1)))
    sg = -drill_axis(layout)[2]
    dT = np.ascontiguousarray(d.T)
    valid = np.isfinite(dT)
    whole = bool(valid.all())
    if not whole:
        dT = np.where(valid, dT, 0.0)
    w = spot_weights(layout, sigma_mm, None if whole else valid)
    E, u = layout.zero, layout.direction
    x, y, z = (_spot_axis(E[:, k, None], dT, u[:, k, None]) for k in range(3))  # (n, h), mm, TCS
    wx, wy = w * x, w * y
    wz = w  # w G_z, G_z = 1 (the micro-plane): w G_z x is wx, its sums wx's (a flat panel's G_z is 1.0 exactly)
    sxy = (rows_dot(wx, x), rows_dot(wx, y), rows_dot(wy, y))
    with np.errstate(divide="ignore", invalid="ignore"):
        gx, gy, c, inv = _solve(wx, wy, wz, z, (sxy[0], sxy[1], wx.sum(0), sxy[2], wy.sum(0), _rows_sum(w)))
        gx0, gy0 = gx, gy
        k = None
        for it in range(1, steps + 1 if full else steps):
            if K3 is None:  # the micro-plane: nothing more to fit; the last pass only keeps its arrays
                break
            # the curvature's terms at (g, c): e_i = sigma rho q^T K_m q / 2, its slope k = sigma rho K_m q
            rho = np.sqrt(1.0 + gx * gx + gy * gy)
            mx, my, mz = -sg * gx / rho, -sg * gy / rho, sg / rho
            zq = z - c
            k = turned_tangent(K3, mx, my, mz, sg)  # K on the fitted tangent plane
            sc = sg * rho
            s00, s01, s02, s11, s12, s22 = (sc * t for t in k)
            kx = s00 * x + s01 * y + s02 * zq
            ky = s01 * x + s11 * y + s12 * zq
            kz = s02 * x + s12 * y + s22 * zq
            e = 0.5 * (x * kx + y * ky + zq * kz)
            Gz = 1.0 + kz
            wz = w * Gz
            sums = (sxy[0], sxy[1], rows_dot(wz, x), sxy[2], rows_dot(wz, y), rows_dot(wz, Gz))
            if it == steps:  # evaluated at the solution only (for the uncertainty)
                inv = inv3(*sums)
                break
            gx, gy, c, inv = _solve(wx, wy, wz, z + (e + kz * c), sums)
    i00 = inv[0]
    ok = np.isfinite(i00) & np.isfinite(gx) & np.isfinite(gy)
    if not whole or n < 3:
        ok &= valid.sum(0) >= 3
    f = sg / np.sqrt(1.0 + gx * gx + gy * gy)
    normal = np.array([-gx * f, -gy * f, f]).T  # (h, 3), a view of (3, h)
    if gx0 is gx:  # the micro-plane: the first step is the fit (the same array where no row is blanked below)
        plane = normal if ok.all() else normal.copy()
    else:
        f0 = sg / np.sqrt(1.0 + gx0 * gx0 + gy0 * gy0)
        plane = np.array([-gx0 * f0, -gy0 * f0, f0]).T
    normal[~ok] = np.nan
    g = np.array([gx, gy]).T  # (h, 2), a view of (2, h)
    if not full:
        return SurfaceFit(normal, g, c, ok, plane, None, None, None, None, None, None, None)
    i00, i01, i02, i11, i12, i22 = inv
    A = np.empty((2, n, h))  # the slopes' rows of A = M^-1 J^T W, J = -(x, y, G_z) (the offset's is read by nothing)
    for r, (a0, a1, a2) in enumerate(((i00, i01, i02), (i01, i11, i12))):
        np.multiply(wx, -a0, out=A[r])
        A[r] -= wy * a1
        A[r] -= wz * a2
    t = gx * x  # the heights' misfit (and the curvature's height) (z - c) - g_x x - g_y y, in place
    hres = z - c
    hres -= t
    np.multiply(gy, y, out=t)
    hres -= t
    if k is None:  # the micro-plane: G = (-g_x, -g_y, 1) at every spot (spot_slopes), the spots as read
        G = q = Kt = None
        null = _null_vector_plane(x, y) if n == 4 else None
    else:
        zq = z - c
        hres = hres + e
        Kt = np.array([[k[0], k[1], k[2]], [k[1], k[3], k[4]], [k[2], k[4], k[5]]]).transpose(2, 0, 1)  # K_m, (h, 3, 3)
        G = np.stack([kx - gx, ky - gy, Gz]).transpose(2, 1, 0)  # (h, n, 3), views of (3, n, h)
        q = np.stack([x, y, zq]).transpose(2, 1, 0)
        null = null_vector_cols(x, y, Gz) if n == 4 else None  # its sign: the cofactors of (1, x, y) (normals.py)
    return SurfaceFit(normal, g, c, ok, plane, A.transpose(2, 0, 1), G, q, np.broadcast_to(w, x.shape).T, null,
                      hres.T, Kt, (x, y))


def _spot_axis(E, dT, u):
    """``E + d u`` (n, h) of one axis, made in place (the same numbers as ``E + dT * u``)."""
    out = dT * u
    out += E
    return out


def _rows_sum(a):
    """``a.sum(0)`` of a sensor-major array, its rows added in order (as a sum over the sensors of (n, h) arrays is)."""
    out = a[0].copy()
    for r in a[1:]:
        out += r
    return out


def _null_vector_plane(x, y):
    """(h, 4) :func:`metrology.core.sym3.null_vector_cols` ``(x, y, 1)``, its products by the column of ones left
    out (a flat panel's ``G_z`` is 1.0 exactly: the same numbers) and each pair's terms made once."""
    pair = {}
    for j, k in ((2, 3), (1, 3), (1, 2)):
        pair[j, k] = (y[j] - y[k], x[j] - x[k], x[j] * y[k] - x[k] * y[j])

    def det(i, j, k):
        dy, dx, c = pair[j, k]
        return x[i] * dy - y[i] * dx + c

    q = np.stack([det(1, 2, 3), -det(0, 2, 3), det(0, 1, 3), -det(0, 1, 2)])
    return (q / np.sqrt(rows_dot(q, q))).T


def spot_slopes(fit: SurfaceFit):
    """``G_i = dh_i / dS_i`` of a full fit by component, ``(G_x, G_y, G_z)``, each (n, h) or broadcasting to it:
    the surface's own slope at each spot, or the micro-plane's ``(-g_x, -g_y, 1)`` (the same numbers a flat
    panel's surface fit holds: ``0 - g_x`` is ``-g_x``)."""
    if fit.G is None:
        return -fit.g[:, 0], -fit.g[:, 1], 1.0
    return tuple(fit.G.transpose(2, 1, 0))

