"""The budget's terms both fitters share: the reading noise, the calibration's covariance and the
redundant reading's misfit, from a fit's linear map of the spots' heights.

A fitter (the micro-plane, or the local surface) gives, per hole, how each spot's height moves the
tilt, ``A = d g / d h`` ((2, n) per hole, as two sensor-major (n, N) arrays ``A0, A1``), and how a
spot's displacement moves its height, ``G_i = d h_i / d S_i`` (the micro-plane's ``(-g_x, -g_y, 1)``;
the surface's own slope at the spot). Then

- a reading error ``delta d_i`` moves the height by ``(G_i . u_i) delta d_i``;
- a calibration error moves the spot by ``delta E_i + d_i (a e1_i + b e2_i)`` (the chart of
  :mod:`metrology.core.model`), its height by ``r_i . (delta E, a, b)``, ``r_i = (G_i, d_i G_i.e1_i,
  d_i G_i.e2_i)``;

and the tilt's covariance from independent heights of variance ``q_i`` is ``sum_i q_i A_i A_i^T``.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from metrology.core.model import direction_basis
from metrology.measure.budget import CALIBRATION, READING_NOISE, Source
from metrology.measure.estimator import rows_dot, spot_slopes

__all__ = ["reading_sigma", "tilt_cov", "noise_source", "calibration_source", "reading_sources", "redundancy",
           "Redundancy"]


def reading_sigma(layout, sigma_mm=None) -> np.ndarray:
    """(n,) float, mm: each sensor's reading noise (``sigma_mm``, else the layout's; unknown: 0)."""
    sigma = layout.noise_mm if sigma_mm is None else np.broadcast_to(np.asarray(sigma_mm, float), (layout.n,))
    return np.where(np.isfinite(sigma), sigma, 0.0)


def tilt_cov(A0, A1, q) -> np.ndarray:
    """(N, 3): the tilt's covariance ``(00, 01, 11)`` from independent heights of variance ``q (n, N)``,
    ``A0, A1 (n, N)`` the tilt's change per unit height."""
    out = np.empty((A0.shape[1], 3))
    out[:, 0] = rows_dot(A0, q, A0)
    out[:, 1] = rows_dot(A0, q, A1)
    out[:, 2] = rows_dot(A1, q, A1)
    return out


def noise_source(A0, A1, Gu, sigma) -> Source:
    """The reading noise's :class:`Source`: ``Gu (n, N)`` = ``G_i . u_i``, ``sigma (n,)`` mm."""
    return Source(READING_NOISE, tilt_cov(A0, A1, (Gu * sigma[:, None]) ** 2))


def _block_diagonal(cov, n):
    off = cov.copy()
    for i in range(n):
        off[5 * i:5 * i + 5, 5 * i:5 * i + 5] = 0.0
    return not np.any(off)


#: a spot slope's products, ``G_a G_b`` for the six entries ``(a, b)`` of a symmetric 3 x 3 matrix (the off-diagonal
#: ones counted twice in :func:`_spot_forms`)
_PAIRS = ((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2))


def _spot_forms(layout, cov):
    """Each sensor's calibration block as a quadratic form in the spot's slope ``G``: ``r^T C_ii r = G^T (P_0 +
    d P_1 + d^2 P_2) G`` (``r = L(d) G``, ``L = [I; d e1^T; d e2^T]``), the six entries of each ``P_k`` (the
    off-diagonal ones doubled) as (n, 1) arrays, None where every sensor's is 0 (a term left out is an exact 0).
    Made once per layout and covariance (a run asks for the same ones every slice of every batch)."""
    u = np.ascontiguousarray(layout.direction, float)
    c = np.ascontiguousarray(cov, float)
    return _forms(u.tobytes(), c.tobytes(), layout.n)


@functools.lru_cache(maxsize=16)
def _forms(u_bytes, cov_bytes, n):
    u = np.frombuffer(u_bytes, float).reshape(n, 3)
    cov = np.frombuffer(cov_bytes, float).reshape(5 * n, 5 * n)
    e = direction_basis(u)  # (n, 2, 3): the chart axes of each calibrated beam
    B = np.stack([cov[5 * i:5 * i + 5, 5 * i:5 * i + 5] for i in range(n)])  # (n, 5, 5)
    eT = np.transpose(e, (0, 2, 1))
    P0 = B[:, :3, :3]
    P1 = B[:, :3, 3:] @ e + eT @ B[:, 3:, :3]
    P2 = eT @ B[:, 3:, 3:] @ e
    out = []
    for P in (P0, P1, P2):
        entries = [(1.0 if a == b else 2.0) * P[:, a, b, None] for a, b in _PAIRS]
        for x in entries:
            x.setflags(write=False)  # shared by every call
        out.append(tuple(x if np.any(x) else None for x in entries))
    return tuple(out)


def _added(acc, term, fresh):
    """``acc + term`` (``term`` where ``acc`` is None), in place where one of them is a new array of the sum's
    shape (``fresh``: ``term`` is; ``acc`` is whenever it came from here with that shape): the same numbers."""
    if acc is None:
        return term if fresh else np.array(term)
    shape = np.broadcast_shapes(acc.shape, term.shape)
    if acc.shape == shape:
        acc += term
        return acc
    if fresh and term.shape == shape:
        term += acc
        return term
    return acc + term


def calibration_source(layout, cov, dT, G, A0, A1):
    """The calibration's :class:`Source` and each spot's own height variance ``r_i^T C_ii r_i`` ((n, N),
    its sensor's 5 x 5 block: the redundant reading's share).

    Parameters
    ----------
    layout : SensorLayout, n sensors; cov : (5n, 5n) float, mm and rad, the calibration's covariance
    dT : (n, N) float, mm, the readings; G : three (n, N) or (N,) arrays (or 1.0 for ``G_z``), ``G_i`` by component
    A0, A1 : (n, N), the tilt's change per unit height

    A calibration fits each sensor from its own readings, so ``cov`` is block diagonal: the spots are then
    independent (a quadratic form per spot, :func:`_spot_forms`: its terms in ``G`` made per hole where ``G`` is
    the micro-plane's, one per hole); any other covariance is propagated whole.
    """
    n = layout.n
    Gx, Gy, Gz = G
    forms = _spot_forms(layout, cov)
    d2 = dT * dT
    q = None
    for j, (a, b) in enumerate(_PAIRS):
        coef = None  # P_0 + d P_1 + d^2 P_2 of this entry, the terms that are 0 left out
        for P, dk in ((forms[0][j], None), (forms[1][j], dT), (forms[2][j], d2)):
            if P is not None:
                coef = _added(coef, P if dk is None else dk * P, dk is not None)
        if coef is None:
            continue
        m = G[a] * G[b]
        one = isinstance(m, float) and m == 1.0  # x 1.0 is exact: G_z = 1 left out
        q = _added(q, coef if one else coef * m, not one or coef.shape == dT.shape)
    q = 0.0 if q is None else q
    q = np.broadcast_to(q, dT.shape)
    if _block_diagonal(cov, n):
        return Source(CALIBRATION, tilt_cov(A0, A1, q)), q
    e = direction_basis(layout.direction)
    r = [Gx, Gy, Gz] + [dT * (Gx * e[:, k, 0, None] + Gy * e[:, k, 1, None] + Gz * e[:, k, 2, None]) for k in range(2)]
    N = dT.shape[1]
    rows = np.stack([np.broadcast_to(x, dT.shape) for x in r], axis=-1).transpose(1, 0, 2)  # (N, n, 5)
    Sx = (rows * A0.T[:, :, None]).reshape(N, -1)
    Sy = (rows * A1.T[:, :, None]).reshape(N, -1)
    cx, cy = Sx @ cov, Sy @ cov
    C = np.stack([np.einsum("ij,ij->i", cx, Sx), np.einsum("ij,ij->i", cx, Sy), np.einsum("ij,ij->i", cy, Sy)], axis=1)
    return Source(CALIBRATION, C), q


def reading_sources(layout, fit, dT, cov, sigma):
    """What both fitters build from a full :class:`metrology.measure.estimator.SurfaceFit` (one code: a flat
    panel's budget is the micro-plane's to the last bit): ``(A0, A1, Gu, noise, calibration, q_cal)``.

    ``A0, A1`` (n, N) the tilt's change per unit height, ``Gu`` (n, N) ``G_i . u_i``, the two :class:`Source`
    entries and each spot's calibration variance ``q_cal`` (n, N) (0 without ``cov``); ``dT`` (n, N) mm the
    readings, ``cov`` (5n, 5n) or None, ``sigma`` (n,) mm."""
    A0, A1 = fit.A[:, 0, :].T, fit.A[:, 1, :].T
    Gx, Gy, Gz = spot_slopes(fit)  # (n, N) each, or broadcasting to it
    u = layout.direction
    Gu = Gx * u[:, 0, None] + Gy * u[:, 1, None] + Gz * u[:, 2, None]
    noise = noise_source(A0, A1, Gu, sigma)
    if cov is not None:
        cal, q_cal = calibration_source(layout, cov, dT, (Gx, Gy, Gz), A0, A1)
    else:
        cal, q_cal = Source(CALIBRATION, np.zeros((A0.shape[1], 3))), np.zeros(A0.shape)
    return A0, A1, Gu, noise, cal, q_cal


@dataclass(frozen=True)
class Redundancy:
    """The redundant readings' misfit of ``N`` holes (n >= 4; 3: NaN, nothing to check).

    Attributes
    ----------
    residual : (N,) float, mm; 4 sensors: the signed misfit ``rho = q . h``; 5+: the RMS misfit
    residual_z : (N,) float; 4: ``rho`` over its noise sigma (N(0, 1) in control); 5+: ``sqrt(chi2 / (n - 3))``
    signature : (N, n) float or None; 4: ``d rho / d delta_k`` of each sensor's zero
    noise_sd : (N,) float, mm, or None; 4: ``rho``'s sigma from the reading noise
    sd : (N,) float, mm, or None; 4: ``rho``'s sigma from the noise, the calibration and ``extra_var``
    """

    residual: np.ndarray
    residual_z: np.ndarray
    signature: np.ndarray | None = None
    noise_sd: np.ndarray | None = None
    sd: np.ndarray | None = None


def redundancy(null, res, Gu, sigma, q_cal, extra_var=0.0) -> Redundancy:
    """The misfit of the redundant readings: ``null (n, N)`` the unit vectors orthogonal to the fit's
    columns (n = 4, else None), ``res (n, N)`` mm the heights (their misfit where n > 4), ``Gu (n, N)``,
    ``sigma (n,)`` mm, ``q_cal (n, N)`` or 0, ``extra_var`` (N,) mm^2 what else moves ``rho`` (the panel's
    terms)."""
    n, N = res.shape
    if n == 4:
        residual = rows_dot(null, res)
        sig = null * Gu  # d rho / d delta_k
        t = sig * sigma[:, None]
        sd = np.sqrt(rows_dot(t, t))
        with np.errstate(invalid="ignore", divide="ignore"):
            z = residual / sd
        return Redundancy(residual, z, sig.T, sd,
                          np.sqrt(sd * sd + rows_dot(null, null, np.broadcast_to(q_cal, null.shape)) + extra_var))
    if n > 4:
        v = (Gu * sigma[:, None]) ** 2
        with np.errstate(invalid="ignore", divide="ignore"):
            return Redundancy(np.sqrt((res * res).sum(0) / n), np.sqrt((res * res / v).sum(0) / (n - 3)))
    return Redundancy(np.full(N, np.nan), np.full(N, np.nan))
