"""The robust datum-plane fit.

- :mod:`metrology.datum.robust`: :func:`fit_plane_robust` (subsample, RANSAC, refinement,
  the passes over the whole cloud);
- :mod:`metrology.datum.scale`: the least-quantile-of-squares scale and the truncated
  Gaussian of the inlier window;
- :mod:`metrology.datum.form`: the datum's quadratic form and its F-test (:class:`DatumForm`);
- :mod:`metrology.datum.result`: :class:`PlaneFit`, the result.

Reading a cloud file and writing the JSON and the residual map is the job
:func:`metrology.jobs.fit_plane.fit_plane_file`; the text and the figure are in
:mod:`metrology.report.datum`.
"""

from metrology.datum.form import DatumForm
from metrology.datum.result import PlaneFit
from metrology.datum.robust import fit_plane_robust
from metrology.datum.scale import lqs_scale, truncated_normal_std, window_sigmas

__all__ = ["PlaneFit", "DatumForm", "fit_plane_robust", "lqs_scale", "truncated_normal_std", "window_sigmas"]
