"""The result of a datum-plane fit: the plane, its covariance, the inlier statistics and the form test."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
import numpy as np
from metrology.core.plane import Plane


#: default inlier threshold, in robust standard deviations of the residuals (unitless)
INLIER_K_SIGMA = 3.0

#: significance level of the F-test of the quadratic form (unitless)
FORM_ALPHA = 0.01


SIGN_CONVENTION = "A^2 + B^2 + C^2 = 1 and D <= 0: the normal points from the frame origin towards the plane"


def truncated_normal_std(k: float) -> float:
    """Standard deviation of a standard normal variable truncated to ``[-k, k]`` (unitless)."""
    phi = math.exp(-0.5 * k * k) / math.sqrt(2 * math.pi)
    mass = math.erf(k / math.sqrt(2))
    return math.sqrt(1.0 - 2.0 * k * phi / mass)


def window_sigmas(threshold: float, sigma_kept: float) -> float:
    """The window half-width ``k`` (in noise sigmas) that leaves Gaussian residuals
    truncated to ``+-threshold`` with standard deviation ``sigma_kept``.

    Solves ``g(k) / k = sigma_kept / threshold`` (``g`` = :func:`truncated_normal_std`),
    decreasing from ``1/sqrt(3)`` at ``k -> 0`` (residuals filling the window evenly) to 0.
    Clamped to ``[1, 40]``: below 1 the Gaussian model does not describe the residuals,
    above 40 the window is wide open. Unitless.
    """
    if not (threshold > 0) or not (sigma_kept >= 0):
        return math.inf
    target = sigma_kept / threshold
    lo, hi = 1.0, 40.0
    if target >= truncated_normal_std(lo) / lo:
        return lo
    if target <= truncated_normal_std(hi) / hi:
        return hi
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if truncated_normal_std(mid) / mid > target:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


@dataclass(frozen=True)
class DatumForm:
    """The quadratic form of the datum over its best-fit plane.

    ``r(u, v) = c0 + cu u + cv v + cuu u^2 + cuv u v + cvv v^2``, ``r`` the signed
    residual (mm, positive on the normal's side), ``(u, v)`` mm along ``axes`` from
    ``origin``.

    Attributes
    ----------
    origin : (3,) float, mm, cloud frame
        The inliers' centroid.
    axes : (2, 3) float, unit, cloud frame
        ``u`` (largest in-plane spread) and ``v``; ``(u, v, normal)`` is right-handed.
    coefficients : (6,) float
        ``c0`` mm, ``cu, cv`` unitless, ``cuu, cuv, cvv`` 1/mm.
    stderr : (6,) float
        1-sigma of ``coefficients``, same units.
    f_statistic : float
        F of the three quadratic terms against the plane, ``(3, n - 6)`` degrees of freedom.
    p_value : float
        Probability of an F this large from a flat datum with Gaussian noise.
    pv : float, mm
        Peak-to-valley of the fitted quadratic surface over the (subsampled) inliers.
    """

    origin: np.ndarray
    axes: np.ndarray
    coefficients: np.ndarray
    stderr: np.ndarray
    f_statistic: float
    p_value: float
    dof: tuple
    pv: float
    alpha: float = FORM_ALPHA

    @property
    def significant(self) -> bool:
        return bool(self.p_value < self.alpha)

    def evaluate(self, u, v):
        """Fitted residual (mm) at in-plane coordinates ``u, v`` (mm, any matching shapes)."""
        c = self.coefficients
        return c[0] + c[1] * u + c[2] * v + c[3] * u * u + c[4] * u * v + c[5] * v * v

    def to_dict(self) -> dict:
        c, s = self.coefficients, self.stderr
        names = ("c0_mm", "cu", "cv", "cuu_per_mm", "cuv_per_mm", "cvv_per_mm")
        return {
            "model": "r = c0 + cu*u + cv*v + cuu*u^2 + cuv*u*v + cvv*v^2 (r, u, v in mm)",
            "origin": [float(x) for x in self.origin],
            "u_axis": [float(x) for x in self.axes[0]],
            "v_axis": [float(x) for x in self.axes[1]],
            "coefficients": {k: float(x) for k, x in zip(names, c)},
            "sigma": {k: float(x) for k, x in zip(names, s)},
            "f_statistic": float(self.f_statistic),
            "dof": [int(self.dof[0]), int(self.dof[1])],
            "p_value": float(self.p_value),
            "alpha": float(self.alpha),
            "significant": self.significant,
            "pv_mm": float(self.pv),
        }


@dataclass(frozen=True)
class PlaneFit:
    """The result of :func:`fit_plane_robust`.

    Attributes
    ----------
    plane : Plane
        In the cloud frame; unit normal, ``D <= 0``.
    covariance : (4, 4) float
        Covariance of ``(A, B, C, D)``: unitless for the normal, mm for D.
    centroid : (3,) float, mm, cloud frame
        Centroid of the inliers (the plane passes through it).
    axes : (2, 3) float, unit, cloud frame
        In-plane axes: largest and smallest spread of the inliers.
    n_points, n_inliers : int
    threshold : float, mm
        Inlier threshold on the absolute distance to the plane.
    threshold_auto : bool
        True when the threshold was derived from the data (``INLIER_K_SIGMA`` robust sigma).
    noise_sigma : float, mm
        ``sqrt(sum r^2 / (n_inliers - 3))`` over the inliers (NaN with 3 inliers).
    rms, residual_min, residual_max : float, mm
        Of the inliers' signed residuals to ``plane``.
    form : DatumForm or None
        None when there are too few inliers (< 7) or they do not span the plane.
    seed : int
    ransac_points : int
        Size of the subsample RANSAC ran on.
    selection_plane : (4,) float
        The plane (A, B, C, D) the inliers were selected against (the refined subsample
        plane); :meth:`inliers` uses it to recover the exact inlier set.
    window_k : float
        The inlier band in noise sigmas (:func:`window_sigmas`); the covariance carries
        the factor ``1 / g(window_k)^4``.
    source, format : str
        The file fitted and its format, when fitted from a file.
    """

    plane: Plane
    covariance: np.ndarray
    centroid: np.ndarray
    axes: np.ndarray
    n_points: int
    n_inliers: int
    threshold: float
    threshold_auto: bool
    noise_sigma: float
    rms: float
    residual_min: float
    residual_max: float
    form: DatumForm | None
    seed: int
    ransac_points: int
    selection_plane: np.ndarray = field(repr=False)
    window_k: float = math.inf
    source: str = ""
    format: str = ""

    @property
    def inlier_ratio(self) -> float:
        return self.n_inliers / self.n_points

    @property
    def flatness(self) -> float:
        """Peak-to-valley of the inliers' residuals to the fitted plane, mm."""
        return self.residual_max - self.residual_min

    @property
    def max_abs_residual(self) -> float:
        return max(abs(self.residual_min), abs(self.residual_max))

    @property
    def normal_sigma(self) -> float:
        """RMS angular error of the normal, rad: ``sqrt(trace of the normal's covariance)``."""
        return float(math.sqrt(max(np.trace(self.covariance[:3, :3]), 0.0)))

    @property
    def offset_sigma(self) -> float:
        """1-sigma of D, mm (includes the normal's tilt acting over the centroid's lever arm)."""
        return float(math.sqrt(max(self.covariance[3, 3], 0.0)))

    @property
    def offset_sigma_at_centroid(self) -> float:
        """1-sigma of the plane's position along its normal at the centroid, mm."""
        inflate = truncated_normal_std(self.window_k) ** -4 if math.isfinite(self.window_k) else 1.0
        return float(self.noise_sigma * math.sqrt(inflate / self.n_inliers))

    def residuals(self, points):
        """Signed distances ``(m,)`` mm of ``points`` ``(m, 3)`` mm, cloud frame, to the plane."""
        return self.plane.distance(points)

    def inliers(self, points):
        """Boolean mask ``(m,)`` of the inliers among ``points`` ``(m, 3)`` mm (the cloud fitted)."""
        n, d = self.selection_plane[:3], self.selection_plane[3]
        return np.abs(np.asarray(points, dtype=float) @ n + d) <= self.threshold

    def to_dict(self) -> dict:
        """Plain-JSON view (degrees named ``_deg``; NaN as None). ``normal`` and ``offset``
        are what :meth:`metrology.plane.Plane.from_json` reads."""

        def num(x):
            x = float(x)
            return x if math.isfinite(x) else None

        out = {
            "schema": "metro.plane/1",
            "source": self.source,
            "format": self.format,
            "frame": "cloud",
            "units": "mm",
            "normal": [float(x) for x in self.plane.normal],
            "offset": float(self.plane.offset),
            "sign_convention": SIGN_CONVENTION,
            "centroid": [float(x) for x in self.centroid],
            "n_points": int(self.n_points),
            "n_inliers": int(self.n_inliers),
            "inlier_ratio": float(self.inlier_ratio),
            "threshold_mm": float(self.threshold),
            "threshold_source": f"auto: {INLIER_K_SIGMA:g} x robust sigma" if self.threshold_auto else "user",
            "noise_sigma_mm": num(self.noise_sigma),
            "residual_dof": int(self.n_inliers - 3),
            "window_sigmas": num(self.window_k),
            "rms_mm": float(self.rms),
            "max_abs_residual_mm": float(self.max_abs_residual),
            "flatness_mm": float(self.flatness),
            "normal_sigma_deg": num(math.degrees(self.normal_sigma)),
            "offset_sigma_mm": num(self.offset_sigma),
            "offset_sigma_at_centroid_mm": num(self.offset_sigma_at_centroid),
            "covariance": [[num(x) for x in row] for row in self.covariance],
            "form": None if self.form is None else self.form.to_dict(),
            "seed": int(self.seed),
            "ransac_points": int(self.ransac_points),
        }
        return out
