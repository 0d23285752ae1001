"""The datum plane as a nuisance of the calibration, with the scan's covariance as its prior.

The datum plane ``N . p + D = 0`` (tracker frame) is fitted from a tracker scan and is not exact:
``fit-plane`` states the covariance of ``(A, B, C, D)``. Over poses a few hundred mm apart a tilt
of tens of urad is several um at the spots, as large as the sensors' noise. Here the plane is
moved by the nuisance ``phi = (t1, t2, dD)``: ``N' = normalise(N + t1 e1 + t2 e2)``, ``D' = D + dD``
(``e1, e2`` = :func:`~metrology.core.plane.plane_basis` of ``N``; rad, rad, mm), and ``phi`` is
estimated jointly with every sensor's chart errors ``theta (n, 5)``: the whitened readings of all
sensors (``r / s_i``, ``s_i`` the sensor's scatter the estimator reports) and the prior rows
``L^-1 phi`` (``P = L L^T`` the scan's covariance in ``phi``'s coordinates). To first order the
joint information is ``H = J^T J``; its inverse's sensor block is the calibration's covariance with
the datum marginalised (the sensors now correlated through the shared plane), and its per-sensor
blocks of the readings' rows alone the covariance conditional on the plane (what metro reported
before). The *datum's share* is the difference.

For ``lsq`` (the default) the sensors' estimates are those of the joint fit; for the other
estimators their own estimates are kept and the datum's share is added to their covariance.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from metrology.core.model import readings
from metrology.core.plane import plane_basis

__all__ = ["DatumNuisance", "plane_prior", "fit_with_datum", "PHI_NAMES", "JOINT_ITERATIONS"]

#: the nuisance's coordinates: two tilts of the normal (rad) about the plane's in-plane axes, the offset (mm)
PHI_NAMES = ("tilt_1", "tilt_2", "offset")
#: Gauss-Newton steps of the joint fit from the per-sensor estimate (the plane moves by its
#: uncertainty, urad and um: the problem is nearly linear there; two steps reach 1e-12 of the cost)
JOINT_ITERATIONS = 4
#: central-difference steps of the readings' Jacobian: chart (mm, rad) and the nuisance (rad, rad, mm)
_STEP_THETA = 1e-6
_STEP_PHI = np.array([1e-7, 1e-7, 1e-6])


def plane_prior(normal, cov4) -> np.ndarray:
    """``(3, 3)``: the covariance of ``phi = (t1, t2, dD)`` (rad, rad, mm) from that of
    ``(A, B, C, D)`` ``cov4 (4, 4)`` (unitless normal, mm), tracker frame."""
    e = plane_basis(np.asarray(normal, float))
    T = np.zeros((3, 4))
    T[0, :3], T[1, :3], T[2, 3] = e[0], e[1], 1.0
    P = T @ np.asarray(cov4, float) @ T.T
    return 0.5 * (P + P.T)


def _moved(normal, offset, phi):
    e = plane_basis(np.asarray(normal, float))
    n = normal + phi[0] * e[0] + phi[1] * e[1]
    s = np.linalg.norm(n)
    return n / s, (offset + phi[2]) / s


@dataclass(frozen=True)
class DatumNuisance:
    """The datum plane estimated with the sensors.

    Attributes
    ----------
    prior : (3, 3) float, the scan's covariance of ``phi`` (rad, rad, mm)
    phi : (3,) float, the joint fit's plane correction (rad, rad, mm), tracker frame
    posterior : (3, 3) float, its covariance after the readings
    cov_conditional : (5n, 5n) float, mm and rad, the sensors' covariance with the plane held
        (block diagonal), in the estimator's chart (around the nominal directions)
    cov_marginal : (5n, 5n) float, the same with the plane's uncertainty carried
    normal, offset : (3,) float, unit and float, mm: the plane the readings were finally fitted on
    moved : bool, the sensors' estimates are the joint fit's (``lsq``) or the estimator's own
    """

    prior: np.ndarray
    phi: np.ndarray
    posterior: np.ndarray
    cov_conditional: np.ndarray
    cov_marginal: np.ndarray
    normal: np.ndarray
    offset: float
    moved: bool

    @property
    def share(self) -> np.ndarray:
        """``(5n,)`` float: the datum's share of each parameter's variance, ``1 - cond / marginal``."""
        c, m = np.diag(self.cov_conditional), np.diag(self.cov_marginal)
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(m > 0, np.clip(1.0 - c / m, 0.0, 1.0), 0.0)

    @property
    def stderr_datum(self) -> np.ndarray:
        """``(5n,)`` float, mm and rad: the datum's part of each standard uncertainty,
        ``sqrt(marginal - conditional)`` (the two add in quadrature)."""
        return np.sqrt(np.maximum(np.diag(self.cov_marginal) - np.diag(self.cov_conditional), 0.0))

    def to_dict(self) -> dict:
        sp, sq = np.sqrt(np.maximum(np.diag(self.prior), 0)), np.sqrt(np.maximum(np.diag(self.posterior), 0))
        return {"estimated_with_sensors": True, "moved_sensors": self.moved,
                "prior_stderr": {"tilt_urad": [float(1e6 * sp[0]), float(1e6 * sp[1])], "offset_um": float(1e3 * sp[2])},
                "correction": {"tilt_urad": [float(1e6 * self.phi[0]), float(1e6 * self.phi[1])],
                               "offset_um": float(1e3 * self.phi[2])},
                "posterior_stderr": {"tilt_urad": [float(1e6 * sq[0]), float(1e6 * sq[1])],
                                     "offset_um": float(1e3 * sq[2])},
                "share_of_variance_max": float(np.max(self.share)) if self.share.size else 0.0}


def fit_with_datum(nominal, export, normal, offset, cov4, theta0, sigma, move=True):
    """The sensors' chart errors and the datum plane fitted jointly (see the module docstring).

    Parameters
    ----------
    nominal : SensorLayout, the chart's centre
    export : TrackerExport (columns in ``nominal.names`` order): the poses and readings
    normal : (3,) float, unit, tracker frame; offset : float, mm: the plane as fitted to the scan
    cov4 : (4, 4) float, covariance of ``(A, B, C, D)`` (unitless normal, mm)
    theta0 : (n, 5) float, mm and rad, the estimator's chart errors (the start)
    sigma : (n,) float, mm, each sensor's reading scatter (the whitening)
    move : bool, estimate ``theta`` jointly (True, ``lsq``) or keep ``theta0`` and only carry the
        plane's uncertainty into the covariance

    Returns
    -------
    theta : (n, 5) float; nuisance : DatumNuisance
    """
    from metrology.calibration.engine import geometry
    from metrology.core.frames import plane_in_tcs

    n = nominal.n
    d = export.d
    ok = np.isfinite(d)
    sig = np.asarray(sigma, float)
    P = plane_prior(normal, cov4)
    # the prior's whitening: a direction of zero prior variance is a plane held there (exact)
    w, V = np.linalg.eigh(P)
    keep = w > 1e-12 * max(float(np.max(w)), 1e-300)
    Winv = (V[:, keep] / np.sqrt(w[keep])).T  # (k, 3): rows whiten phi

    def predict(theta, phi):
        nn, dd = _moved(normal, offset, phi)
        N, D = plane_in_tcs(nn, dd, export.tcs2tracker_rot, export.tcs2tracker_trans)
        zero, u = geometry(nominal, theta)
        return readings(zero, u, N, D)[0]

    def residual(x):
        th, phi = x[:5 * n].reshape(n, 5), x[5 * n:]
        R = (d - predict(th, phi)) / sig
        return np.concatenate([R[ok], Winv @ phi])

    def jacobian(x):
        cols = []
        steps = np.r_[np.full(5 * n, _STEP_THETA), _STEP_PHI]
        for k, h in enumerate(steps):
            xp, xm = x.copy(), x.copy()
            xp[k] += h
            xm[k] -= h
            cols.append((residual(xp) - residual(xm)) / (2 * h))
        return np.stack(cols, axis=1)

    x = np.r_[np.asarray(theta0, float).ravel(), np.zeros(3)]
    if move:
        for _ in range(JOINT_ITERATIONS):
            J, r = jacobian(x), residual(x)
            scale = np.linalg.norm(J, axis=0)
            scale = np.where(scale > 0, scale, 1.0)
            step = -np.linalg.lstsq(J / scale, r, rcond=1e-12)[0] / scale
            if not np.all(np.isfinite(step)):
                break
            x_new = x + step
            if float(residual(x_new) @ residual(x_new)) > float(r @ r):
                break
            x = x_new
    J = jacobian(x)
    scale = np.linalg.norm(J, axis=0)
    scale = np.where(scale > 0, scale, 1.0)
    Js = J / scale
    M = np.linalg.pinv(Js.T @ Js, rcond=1e-14, hermitian=True) / np.outer(scale, scale)
    M = 0.5 * (M + M.T)
    m_rows = int(ok.sum())
    C = np.zeros((5 * n, 5 * n))
    for i in range(n):  # the plane held: each sensor from its own readings' rows
        sl = slice(5 * i, 5 * i + 5)
        Ji = J[:m_rows, sl]
        si = np.linalg.norm(Ji, axis=0)
        si = np.where(si > 0, si, 1.0)
        C[sl, sl] = np.linalg.pinv((Ji / si).T @ (Ji / si), rcond=1e-14, hermitian=True) / np.outer(si, si)
    phi = x[5 * n:]
    nn, dd = _moved(normal, offset, phi)
    nuis = DatumNuisance(P, phi, M[5 * n:, 5 * n:], C, M[:5 * n, :5 * n], nn, float(dd), bool(move))
    return x[:5 * n].reshape(n, 5), nuis
