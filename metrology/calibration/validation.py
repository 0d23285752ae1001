"""Validation on held-out poses: the normal deviation per pose for each layout (nominal, calibrated)."""

from __future__ import annotations

from dataclasses import dataclass, field
import numpy as np
from metrology.calibration.dataset import Dataset, check
from metrology.core.stats import describe


@dataclass(frozen=True)
class ValidationReport:
    """Angular deviation of the measured normal from the datum normal, per layout.

    Attributes
    ----------
    pose_id : tuple of str, length p
    labels : tuple of str, one per layout
    deviation : (k, p) float, rad; NaN where fewer than 3 readings
    n_readings : (p,) int, readings per pose
    n_sensors : int
    sources : dict
    no_reading : dict or None
        The "no reading" codes dropped on loading (value, count, readings), None when none was.
    """

    pose_id: tuple
    labels: tuple
    deviation: np.ndarray
    n_readings: np.ndarray
    n_sensors: int
    sources: dict = field(default_factory=dict)
    no_reading: dict | None = None

    def stats_deg(self, k: int) -> dict:
        """max / mean / std (sample, ddof=1) of the deviation of layout ``k``, deg, and the poses counted."""
        a = np.rad2deg(self.deviation[k])
        return {**describe(a), "n_poses": int(np.isfinite(a).sum())}

    def to_dict(self) -> dict:
        return {
            "sources": self.sources,
            "n_poses": len(self.pose_id),
            "layouts": {lab: {**self.stats_deg(k), "deviation_deg": np.rad2deg(self.deviation[k])}
                        for k, lab in enumerate(self.labels)},
            "pose_id": list(self.pose_id),
            "n_readings": self.n_readings,
            **({"no_reading": self.no_reading} if self.no_reading else {}),
        }


def validate(dataset: Dataset, layouts: dict, sources=None) -> ValidationReport:
    """Angular deviation of the sensors' normal from the datum normal, per pose and layout.

    Parameters
    ----------
    dataset : Dataset
        Validation poses, readings and the datum (its own layout is not used).
    layouts : dict of label -> SensorLayout
        Each is checked against the export (same sensors, readings within range); a layout's head
        terms are removed from the readings it is judged on (:mod:`metrology.calibration.terms`).

    Returns
    -------
    ValidationReport
        The normal of each pose is Eqs. 17-19 with all four readings, or the
        least-squares plane of the projection points when a reading is missing (NaN with
        fewer than 3); compared, unoriented, with the datum normal in that pose's TCS.
    """
    from metrology.core.normals import angle_between, micro_plane_normal

    if not layouts:
        raise ValueError("validate: no layout given")
    obs = dataset.obs
    dev = []
    for label, layout in layouts.items():
        export = check(dataset.export, layout, f"layout {label}")
        d = export.d
        if layout.effects is not None:  # the layout's head terms removed from the readings it judges
            from metrology.calibration.terms import corrected_obs, dataset_covariates
            from metrology.core.observations import Observations

            cov = dataset_covariates(layout, obs, export, dataset.plane, dataset.datum_points)
            d = corrected_obs(layout.effects, Observations(obs.normal, obs.offset, d), cov).d
        n = micro_plane_normal(layout.zero, layout.direction, d)
        dev.append(angle_between(n, obs.normal))
    dev = np.array(dev)
    if not np.any(np.isfinite(dev[0])):
        raise ValueError("validate: no pose has 3 or more readings")
    nread = np.isfinite(dataset.export.d).sum(axis=1)
    return ValidationReport(tuple(dataset.export.pose_id), tuple(layouts), dev, nread, int(dataset.export.d.shape[1]),
                            dict(sources or {}), dataset.no_reading_dict() if dataset.dropped else None)
