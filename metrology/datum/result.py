"""The result of the robust datum-plane fit: :class:`PlaneFit`."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from metrology.core.plane import Plane
from metrology.core.schema import schema_tag
from metrology.datum.form import DatumForm
from metrology.datum.scale import INLIER_K_SIGMA, truncated_normal_std

__all__ = ["PlaneFit", "SIGN_CONVENTION"]

SIGN_CONVENTION = "A^2 + B^2 + C^2 = 1 and D <= 0: the normal points from the frame origin towards the plane"


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
    threshold_ran_away: bool = False
    #: the automatic threshold is the floor (the residuals' robust sigma is 0: noise-free points)
    threshold_at_floor: bool = False
    #: what the reader did (:meth:`metrology.io.clouds.CloudRead.to_dict`), when read from a file
    read: dict | None = None

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
        are what :meth:`metrology.core.plane.Plane.from_json` reads."""

        def num(x):
            x = float(x)
            return x if math.isfinite(x) else None

        out = {
            "schema": schema_tag("plane"),
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
            "threshold_source": ("user" if not self.threshold_auto else
                                 "auto: the floor (the robust sigma of the residuals is 0: noise-free points)"
                                 if self.threshold_at_floor else
                                 f"auto: {INLIER_K_SIGMA:g} x robust sigma" if not self.threshold_ran_away else
                                 f"auto: {INLIER_K_SIGMA:g} x the least-quantile sigma of the densest plane (the refined "
                                 "threshold ran away: more than one surface near the datum)"),
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
        if self.read is not None:
            out["read"] = self.read
        return out
