"""Rule 18 given the causes named: is the datum plane off its scan once the named causes are in the null?

The first test of the datum plane (:func:`metrology.diagnosis.datum.datum_plane`) places the plane
with the base model alone, each sensor whitened by its own scatter and the sensors independent. An
effect the base model does not have leaks into the plane there: a pose error moves every spot of a
pose together (its spread is shared by the sensors of a pose, so the plane's correction varies far
more than independent sensors allow), and a zero that follows the temperature moves the plane's
offset when the temperature follows the poses. That test is a screen. The plane is named off its
scan (``datum_tilt``) only where it stays off given the causes the diagnosis named
(:func:`plane_given_causes`):

    r0 = J_phi phi + X beta + e,    phi ~ N(0, P) under the null,  e ~ N(0, V)

``r0`` (mm) the residuals of the joint fit of the named causes taken back to the scan's plane,
``J_phi (m, 3)`` the readings' derivative by the plane's correction ``phi`` (two tilts, rad, and the
offset, mm, as :mod:`metrology.calibration.datum_prior` moves it), ``X`` every parameter of the
named model (each sensor's chart, each cause's values, one column per pose for a per-pose cause:
a rigid pose error's offset and tilts a pose absorb any plane, whose correction then has no
direction the readings inform), ``P`` the scan's covariance of ``phi``, ``V`` the readings'
covariance: each sensor's scatter under the named model (never below its stated noise), and, for
a pose error named as a random effect, its covariance shared by the sensors of a pose. With
``X`` profiled out (``~`` the whitened projection off ``X``), ``b = J~^T r~`` has covariance
``A + A P A`` (``A = J~^T J~``) under the null: ``chi2 = b^T (A + A P A)^+ b`` over the directions
the readings inform (beyond :data:`MIN_INFORMATION` of the prior's).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from metrology.core.model import jacobian_raw, readings
from metrology.core.plane import plane_basis

__all__ = ["PlaneGiven", "plane_given_causes", "MIN_INFORMATION"]

#: directions of ``phi`` whose information from the readings is below this fraction of the scan's
#: (prior-whitened eigenvalue) are not tested: the readings cannot move the plane there
MIN_INFORMATION = 1e-4
#: central-difference steps of the plane's correction (rad, rad, mm)
_STEP_PHI = np.array([1e-7, 1e-7, 1e-6])


@dataclass(frozen=True)
class PlaneGiven:
    """The plane's correction tested given the named causes (:func:`plane_given_causes`).

    given : tuple of str, the labels of the causes in the null; chi2 : float; dof : int, the
    directions the readings inform given them; p : float (1.0 where none)."""

    given: tuple
    chi2: float
    dof: int
    p: float

    def to_dict(self) -> dict:
        return {"given": list(self.given), "chi2": self.chi2, "dof": self.dof, "p": self.p}


def _moved(normal, offset, phi):
    """The plane ``(normal (3,), offset)`` moved by ``phi``, as the calibration's datum nuisance does."""
    e = plane_basis(np.asarray(normal, float))
    n = normal + phi[0] * e[0] + phi[1] * e[1]
    s = float(np.linalg.norm(n))
    return n / s, (offset + phi[2]) / s


def _plane_jacobian(ds, scan, phi_used, zero, u):
    """``(p, n, 3)`` mm per unit of ``phi``: the readings' derivative by the plane's correction at
    ``phi_used`` (the correction the diagnosis used), around the scan's plane ``scan``."""
    from metrology.core.frames import plane_in_tcs

    ex = ds.export

    def d0(phi):
        nn, dd = _moved(scan.normal, scan.offset, phi)
        N, D = plane_in_tcs(nn, dd, ex.tcs2tracker_rot, ex.tcs2tracker_trans)
        return readings(zero, u, N, D)[0]

    cols = []
    for k, h in enumerate(_STEP_PHI):
        dp = np.zeros(3)
        dp[k] = h
        cols.append((d0(phi_used + dp) - d0(phi_used - dp)) / (2 * h))
    return np.stack(cols, axis=-1), d0(phi_used) - d0(np.zeros(3))


def _nuisance(fit, obs, cov, zero, u):
    """``(p, n, k)``: every parameter of the named model: each sensor's chart (its readings only)
    and every component's columns (a per-pose component's one block a pose)."""
    p, n = obs.d.shape
    J = jacobian_raw(zero, u, obs.normal, obs.offset)  # (p, n, 6)
    cols = np.zeros((p, n, 6 * n))
    for i in range(n):
        cols[:, i, 6 * i:6 * i + 6] = J[:, i]
    d0 = readings(zero, u, obs.normal, obs.offset)[0]
    blocks = [cols] + [np.asarray(c.jacobian(c.values, d0, cov), float) for c in fit.components]
    return np.concatenate(blocks, axis=-1)


def _pose_covariance(cov, s, random_pose):
    """``(p, n, n)`` mm^2: the readings' covariance a pose, the sensors' scatter ``s (n,)`` and, for a
    random pose error ``(var_offset mm^2, var_tilt rad^2)``, its share common to a pose's spots."""
    p, n = cov.inv_nu.shape
    V = np.broadcast_to(np.diag(s**2), (p, n, n)).copy()
    if random_pose is not None:
        a = cov.inv_nu
        b = cov.spot_st[..., 0] * cov.inv_nu
        c = cov.spot_st[..., 1] * cov.inv_nu
        V += random_pose[0] * np.einsum("pi,pj->pij", a, a) + random_pose[1] * (
            np.einsum("pi,pj->pij", b, b) + np.einsum("pi,pj->pij", c, c))
    return V


def plane_given_causes(ds, scan, plane_cov, phi_used, fit, cov, sigma, labels=(), random_pose=None) -> PlaneGiven:
    """The datum plane's correction against its scan's covariance given the named causes (see the
    module).

    ds : Dataset on the plane the diagnosis used; scan : Plane, the scan's; plane_cov : (4, 4), the
    scan's covariance of ``(A, B, C, D)``; phi_used : (3,) the correction of the plane used (rad,
    rad, mm); fit : Fit, the joint fit of the named causes on it (the base fit where none); cov :
    Covariates; sigma : (n,) mm, the stated noise; labels : the causes' labels (reported);
    random_pose : ``(var_offset mm^2, var_tilt rad^2)`` of a pose error named as a random effect, or None.
    """
    from scipy import stats

    from metrology.calibration.datum_prior import plane_prior
    from metrology.calibration.engine import geometry

    obs = ds.obs
    zero, u = geometry(ds.layout, fit.theta)
    Jphi, moved = _plane_jacobian(ds, scan, np.asarray(phi_used, float), zero, u)
    r0 = fit.residual + moved  # the residuals were the plane at the scan's: d - d0(0) - terms
    ok = np.isfinite(r0)
    m_i = ok.sum(axis=0)
    scatter = np.sqrt(np.nansum(fit.residual**2, axis=0) / np.maximum(m_i, 1))
    s = np.maximum(np.asarray(sigma, float), np.where(np.isfinite(scatter), scatter, 0.0))
    V = _pose_covariance(cov, s, random_pose)
    X = _nuisance(fit, obs, cov, zero, u)
    rows_r, rows_J, rows_X = [], [], []
    for q in range(obs.d.shape[0]):  # whiten each pose by its covariance (its finite readings)
        k = np.flatnonzero(ok[q])
        if not len(k):
            continue
        w, E = np.linalg.eigh(V[q][np.ix_(k, k)])
        W = (E / np.sqrt(np.maximum(w, 1e-300))).T
        rows_r.append(W @ r0[q, k])
        rows_J.append(W @ Jphi[q, k])
        rows_X.append(W @ X[q, k])
    r, J, Xw = np.concatenate(rows_r), np.concatenate(rows_J), np.concatenate(rows_X)
    Xw = Xw[:, np.linalg.norm(Xw, axis=0) > 0]
    U, sv, _ = np.linalg.svd(Xw, full_matrices=False)
    Q = U[:, sv > 1e-10 * max(float(sv[0]) if len(sv) else 0.0, 1e-300)]
    Jt, rt = J - Q @ (Q.T @ J), r - Q @ (Q.T @ r)
    A, bvec = Jt.T @ Jt, Jt.T @ rt
    P = plane_prior(scan.normal, plane_cov)
    wp, Vp = np.linalg.eigh(P)
    L = Vp * np.sqrt(np.maximum(wp, 0.0))  # P = L L^T
    At, bt = L.T @ A @ L, L.T @ bvec
    a, E = np.linalg.eigh(0.5 * (At + At.T))
    keep = a > MIN_INFORMATION
    z = (E[:, keep].T @ bt) / np.sqrt(a[keep] + a[keep] ** 2)
    chi2, dof = float(z @ z), int(keep.sum())
    return PlaneGiven(tuple(labels), chi2, dof, float(stats.chi2.sf(chi2, dof)) if dof else 1.0)
