"""The datum plane from a laser-tracker cloud: a robust fit, its uncertainty and its form."""

from metrology.datum.result import DatumForm, PlaneFit
from metrology.datum.robust import fit_plane_robust, lqs_scale

__all__ = ["DatumForm", "PlaneFit", "fit_plane_robust", "lqs_scale"]
