"""Effects of the set-up and of single readings: datum form, pose error, outliers (registry entries)."""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from metrology.core.effects.base import Component

__all__ = ["PlaneForm", "PoseError", "Outliers"]


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
    advice = "spots over the whole datum, each region seen at several tilts"
    size_meaning = "bow b_ss mm at 100 mm (b_st = 0.3, b_tt = -0.5 of it)"
    plot_key = "spot_s_mm"
    #: the quadratic part (bow, saddle, twist): what the datum cloud is compared on
    key_params = ("b_ss_mm", "b_st_mm", "b_tt_mm")
    setup = True

    @classmethod
    def candidates_for_setup(cls, names, cov, flags=None):
        return [cls((), names=names)]

    @classmethod
    def hidden(cls, i, size):
        return cls((), [0.0, 0.0, size, 0.3 * size, -0.5 * size])

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
    advice = "repeated poses, or more sensors per pose"
    size_meaning = "1-sigma TCS position error per axis, mm"
    plot_term = False
    setup = True

    @classmethod
    def candidates_for_setup(cls, names, cov, flags=None):
        return [cls((), names=names, n_poses=cov.n_poses)]
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
    advice = "the flagged poses repeated"
    size_meaning = "3 gross readings of +-size mm"
    plot_term = False

    @classmethod
    def candidates_for_sensor(cls, i, names, cov):
        return []  # one candidate for all flagged readings: candidates_for_setup

    @classmethod
    def candidates_for_setup(cls, names, cov, flags=None):
        if flags is None or not np.any(flags):
            return []
        return [cls(tuple(sorted(set(np.argwhere(flags)[:, 1].tolist()))), names=names, flags=flags)]

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

