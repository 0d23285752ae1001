"""The measurement model of the paper, section 3.1 (Eqs. 1-9), vectorised.

A sensor has a zero point ``E`` (mm, TCS) and a beam direction ``u`` (TCS). A plane is
``N . p + D = 0`` with unit ``N``. The beam ``E + t u`` meets the plane at
``t = -(N.E + D) / (N.u)`` and the reading is the distance from ``E`` to that point,

    d = -(N.E + D) |u| / (N.u)                                    (Eqs. 1-3)

which does not change when ``u`` is scaled: of the six numbers (x, y, z, m, n, q) only
five are identifiable (the *gauge*: the direction scale). The raw six-number Jacobian of
Eq. 9 is given for the paper's EKF; it always has ``[0, 0, 0, u]`` in its null space.
The well-posed parametrisation used by metro's own estimators is the five-number chart

    theta = (x, y, z, a, b),    u(a, b) = normalise(u0 + a e1 + b e2)

around a reference direction ``u0`` with ``e1, e2`` an orthonormal basis of the plane
perpendicular to ``u0`` (``a``, ``b`` are the tangents of the tilt angles, in rad at
small angles).

Invalid geometry (beam parallel to the plane, plane behind the sensor, NaN input) is
returned as a ``valid`` mask and NaN readings, never as a silent number.
"""

from __future__ import annotations

import functools

import numpy as np

from metrology.core.layout import PARAMS_TANGENT  # noqa: F401  (re-exported: the model's chart)
from metrology.core.tolerances import BEAM_PARALLEL_COS

__all__ = [
    "readings",
    "jacobian_raw",
    "direction_basis",
    "vector_norm",
    "direction_from_tangent",
    "tangent_from_direction",
    "jacobian_tangent",
    "gauge_null_vector",
    "chart_cov_recentred",
    "PARAMS_RAW",
    "PARAMS_TANGENT",
]

#: names of the paper's six sensor parameters (Eq. 9), in order
PARAMS_RAW = ("x", "y", "z", "m", "n", "q")


def vector_norm(v, axis=-1, keepdims=False):
    """``np.linalg.norm(v, axis=axis, keepdims=keepdims)`` of a float array without its dispatch: the same sum of
    squares, so the same bits. For the small arrays of the calibration's and the diagnosis' inner loops
    (``readings`` is called ~60,000 times a diagnosis), where the dispatch costs more than the sum."""
    return np.sqrt(np.add.reduce(v * v, axis=axis, keepdims=keepdims))


def _geometry(zero, direction, normal, offset):
    """Broadcast inputs; return (s, nu, unorm, direction, normal) with s, nu (p, n), unorm (1, n).

    Called ~60,000 times a diagnosis on a few sensors and ~100 poses, so per-call overhead counts:
    ``unorm`` by :func:`vector_norm`, and ``atleast_2d``/``atleast_1d`` called only where they change something."""
    zero = np.asarray(zero, dtype=float)
    direction = np.asarray(direction, dtype=float)
    normal = np.asarray(normal, dtype=float)
    if normal.ndim < 2:
        normal = np.atleast_2d(normal)
    offset = np.asarray(offset, dtype=float)
    if offset.ndim < 1:
        offset = np.atleast_1d(offset)
    if zero.ndim != 2 or zero.shape[-1] != 3:
        raise ValueError(f"zero: expected shape (n, 3), got {zero.shape}")
    if direction.shape != zero.shape:
        raise ValueError(f"direction: expected shape {zero.shape}, got {direction.shape}")
    if normal.shape[-1] != 3 or offset.shape != normal.shape[:1]:
        raise ValueError(f"plane: normal (p, 3) and offset (p,) expected, got {normal.shape}, {offset.shape}")
    s = -(normal @ zero.T + offset[:, None])  # (p, n): signed distance of E behind the plane
    nu = normal @ direction.T  # (p, n)
    unorm = vector_norm(direction, axis=1)[None, :]  # (1, n)
    return s, nu, unorm, direction, normal


def readings(zero, direction, normal, offset):
    """Predicted readings of every sensor on every plane (Eqs. 1-3).

    Parameters
    ----------
    zero : (n, 3) float, mm, TCS
        Sensor zero points.
    direction : (n, 3) float, TCS
        Beam directions; any non-zero scale (the reading does not depend on it).
    normal : (p, 3) float, TCS
        Unit normals of the plane at each pose.
    offset : (p,) float, mm
        Plane offsets ``D`` at each pose (``N . p + D = 0``).

    Returns
    -------
    d : (p, n) float, mm
        Distance from the zero point to the beam-plane intersection; NaN where invalid.
    valid : (p, n) bool
        False where the beam is parallel to the plane (|cos| < ``BEAM_PARALLEL_COS``),
        the intersection lies behind the sensor, or an input is not finite.
    """
    s, nu, unorm, _, _ = _geometry(zero, direction, normal, offset)
    cos = np.divide(nu, unorm, out=np.zeros(nu.shape), where=unorm > 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        d = s * unorm / nu
    valid = np.isfinite(d) & (np.abs(cos) >= BEAM_PARALLEL_COS) & (d >= 0)
    return np.where(valid, d, np.nan), valid


def jacobian_raw(zero, direction, normal, offset):
    """Jacobian of the readings w.r.t. the paper's six parameters (Eq. 9).

    Parameters are as in :func:`readings`.

    Returns
    -------
    J : (p, n, 6) float
        ``dd/d(x, y, z)`` (unitless) and ``dd/d(m, n, q)`` (mm per unit of direction).
        Its null space always contains ``(0, 0, 0, u)``: scaling the direction.
    """
    s, nu, unorm, direction, normal = _geometry(zero, direction, normal, offset)
    with np.errstate(divide="ignore", invalid="ignore"):
        d = s * unorm / nu
        dE = -(unorm / nu)[..., None] * normal[:, None, :]  # (p, n, 3)
        du = d[..., None] * (
            direction[None, :, :] / (unorm**2)[..., None] - normal[:, None, :] / nu[..., None]
        )
    return np.concatenate([dE, du], axis=-1)


def direction_basis(u0):
    """Orthonormal basis ``(e1, e2)`` of the plane perpendicular to each direction.

    Parameters
    ----------
    u0 : (n, 3) float, TCS
        Reference directions (normalised here).

    Returns
    -------
    basis : (n, 2, 3) float, TCS
        ``basis[i, 0] = e1``, ``basis[i, 1] = e2`` with ``e1 x e2 = u0``. ``e1`` is the
        component of the TCS axis least aligned with ``u0``, made orthogonal to it: a
        deterministic choice, so a chart is reproducible from the layout alone.
    """
    u0 = np.ascontiguousarray(u0, dtype=float)
    return _direction_basis(u0.tobytes(), u0.shape).copy()


@functools.lru_cache(maxsize=256)
def _direction_basis(u0_bytes, shape):
    """:func:`direction_basis` of the directions whose float64 bytes are ``u0_bytes`` (kept: the
    diagnosis asks for the same few layouts' bases thousands of times)."""
    u0 = np.frombuffer(u0_bytes, dtype=float).reshape(shape)
    u0 = u0 / np.linalg.norm(u0, axis=1, keepdims=True)
    axis = np.eye(3)[np.argmin(np.abs(u0), axis=1)]
    e1 = axis - np.sum(axis * u0, axis=1, keepdims=True) * u0
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = np.cross(u0, e1)
    return np.stack([e1, e2], axis=1)


def direction_from_tangent(u0, ab):
    """Unit direction ``normalise(u0 + a e1 + b e2)``.

    Parameters
    ----------
    u0 : (n, 3) float, TCS
        Reference directions (the chart's centre).
    ab : (n, 2) float, rad (tangent of the tilt)
        Chart coordinates.

    Returns
    -------
    u : (n, 3) float, unit, TCS
    """
    u0 = np.asarray(u0, dtype=float)
    u0 = u0 / np.linalg.norm(u0, axis=1, keepdims=True)
    basis = direction_basis(u0)
    w = u0 + np.einsum("nk,nkj->nj", np.asarray(ab, dtype=float), basis)
    return w / np.linalg.norm(w, axis=1, keepdims=True)


def tangent_from_direction(u0, u):
    """Chart coordinates of direction ``u`` around ``u0`` (inverse of :func:`direction_from_tangent`).

    Parameters
    ----------
    u0, u : (n, 3) float, TCS
        Reference and target directions; ``u`` must be within 90 deg of ``u0``.

    Returns
    -------
    ab : (n, 2) float, rad (tangent of the tilt)
    """
    u0 = np.asarray(u0, dtype=float)
    u0 = u0 / np.linalg.norm(u0, axis=1, keepdims=True)
    u = np.asarray(u, dtype=float)
    along = np.sum(u * u0, axis=1)
    if np.any(along <= 0):
        raise ValueError("direction more than 90 deg from its reference: outside the chart")
    basis = direction_basis(u0)
    return np.einsum("nj,nkj->nk", u, basis) / along[:, None]


def jacobian_tangent(zero, u0, ab, normal, offset):
    """Jacobian of the readings w.r.t. the five chart parameters ``(x, y, z, a, b)``.

    Parameters
    ----------
    zero : (n, 3) float, mm, TCS
    u0 : (n, 3) float, TCS
        Chart centres.
    ab : (n, 2) float, rad
        Chart coordinates of the current directions.
    normal : (p, 3) float, TCS
    offset : (p,) float, mm

    Returns
    -------
    J : (p, n, 5) float
        Columns ``dd/dx, dd/dy, dd/dz`` (unitless) and ``dd/da, dd/db`` (mm/rad).
    """
    u0 = np.asarray(u0, dtype=float)
    u0 = u0 / np.linalg.norm(u0, axis=1, keepdims=True)
    basis = direction_basis(u0)
    w = u0 + np.einsum("nk,nkj->nj", np.asarray(ab, dtype=float), basis)
    # d is invariant to the scale of w, so differentiate w.r.t. w itself
    J6 = jacobian_raw(zero, w, normal, offset)
    dab = np.einsum("pnj,nkj->pnk", J6[..., 3:], basis)
    return np.concatenate([J6[..., :3], dab], axis=-1)


def gauge_null_vector(direction):
    """The unidentifiable combination of the six raw parameters of each sensor.

    Parameters
    ----------
    direction : (n, 3) float, TCS

    Returns
    -------
    v : (n, 6) float, unit
        ``(0, 0, 0, u/|u|)``: scaling the beam direction does not change any reading.
    """
    direction = np.asarray(direction, dtype=float)
    u = direction / np.linalg.norm(direction, axis=1, keepdims=True)
    return np.concatenate([np.zeros_like(u), u], axis=1)


def chart_cov_recentred(u0, ab, cov):
    """The chart covariance moved from the chart around ``u0`` to the chart around ``u(ab)``.

    A calibration fits ``(x, y, z, a, b)`` in the chart centred on the nominal direction
    ``u0``; a calibrated layout states its covariance in the chart centred on its own
    direction ``u = direction_from_tangent(u0, ab)``, so a reader needs only the layout. To
    first order ``du = (I - u u^T) / |w| E^T dab`` (``w = u0 + ab E``), and the new chart
    coordinates are ``dab' = E'(u) du``.

    Parameters
    ----------
    u0 : (n, 3) float, TCS, chart centres of the fit
    ab : (n, 2) float, rad, the fitted chart coordinates
    cov : (n, 5, 5) float, mm and rad, per-sensor covariance in the chart around ``u0``;
        or (5n, 5n) for the covariance of all sensors at once

    Returns
    -------
    cov : same shape as the input, mm and rad, in the chart around ``u``
    """
    u0 = np.asarray(u0, dtype=float)
    u0 = u0 / np.linalg.norm(u0, axis=1, keepdims=True)
    E = direction_basis(u0)  # (n, 2, 3)
    w = u0 + np.einsum("nk,nkj->nj", np.asarray(ab, dtype=float), E)
    wn = np.linalg.norm(w, axis=1)
    u = w / wn[:, None]
    proj = (np.eye(3)[None] - u[:, :, None] * u[:, None, :]) / wn[:, None, None]  # (n, 3, 3)
    T2 = np.einsum("nkj,nji,nli->nkl", direction_basis(u), proj, E)  # (n, 2, 2): dab' = T2 dab
    n = len(u0)
    T = np.zeros((n, 5, 5))
    T[:, :3, :3] = np.eye(3)
    T[:, 3:, 3:] = T2
    cov = np.asarray(cov, dtype=float)
    if cov.shape == (n, 5, 5):
        return np.einsum("nij,njk,nlk->nil", T, cov, T)
    if cov.shape == (5 * n, 5 * n):
        from scipy.linalg import block_diag

        Tf = block_diag(*T)
        return Tf @ cov @ Tf.T
    raise ValueError(f"cov must be (n, 5, 5) or (5n, 5n) for n = {n}, got {cov.shape}")
