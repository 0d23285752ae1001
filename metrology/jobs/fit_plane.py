"""``metro fit-plane`` as a job: a cloud file in, the plane JSON and the residual map out."""

from __future__ import annotations

import contextlib
import json
from dataclasses import replace

from metrology.core.progress import notify
from metrology.io.atomic import check_output_file
from metrology.io.names import display_name
from metrology.datum import PlaneFit, fit_plane_robust

__all__ = ["fit_plane_file"]

_PLOT_SUFFIXES = {".png", ".pdf", ".svg"}


def fit_plane_file(cloud, threshold_mm=None, seed=0, out=None, plot=None, units=None, warn=None, report=None,
                   command=None, progress=None, flatness_mm=None, inliers=None, outliers=None,
                   residuals=None) -> PlaneFit:
    """Read a cloud, fit its datum plane, and write the JSON and the residual map.

    Parameters
    ----------
    cloud : str or os.PathLike
        Any format :func:`metrology.io.clouds.read_cloud` reads.
    threshold_mm, seed
        As :func:`fit_plane_robust`.
    out : str or os.PathLike or None
        JSON file (``PlaneFit.to_dict()``), readable by ``Plane.from_json``.
    plot : str or os.PathLike or None
        Residual map (``.png``, ``.pdf``, ``.svg``).
    units : {None, "mm", "m", "in"}
        The unit of the file's numbers (None: mm); the fit is in mm.
    report : str or os.PathLike or None
        One self-contained HTML report (:mod:`metrology.report.html`).
    command : str or None
        The command line the report names (None: this process's).
    warn : callable or None
        ``warn(message)`` for what the caller should know but is not an error: points with
        NaN coordinates dropped (organized scans), a cloud whose size suggests metres. None:
        :func:`warnings.warn`.
    flatness_mm : float or None
        The flatness tolerance the report judges the P-V against (None: none judged).
    inliers, outliers : str or os.PathLike or None
        PLY files of the inlier and outlier points (mm, the cloud's frame), as Open3D and PCL
        read them.
    residuals : str or os.PathLike or None
        Per-point table (``.csv`` or ``.parquet``, :mod:`metrology.jobs.outputs`): x, y, z (mm),
        the signed distance to the fitted plane ``residual_mm`` and ``inlier`` (1/0).
    progress : callable or None
        ``progress(done, total, what)`` at each of 3 stages: read, fit, write
        (:mod:`metrology.core.progress`).

    The outputs are written atomically and together: on any error none exists.
    Errors are ValueError naming the file.
    """
    from metrology.io.atomic import atomic_path
    from metrology.io.clouds import cloud_format, read_cloud_checked

    fmt = cloud_format(cloud)
    if out is not None:
        check_output_file(out, "--out")
    if plot is not None:
        check_output_file(plot, "--plot", _PLOT_SUFFIXES)
    if report is not None:
        from metrology.report.html import check_report_path

        check_report_path(report)
    for path, option in ((inliers, "--inliers"), (outliers, "--outliers")):
        if path is not None:
            check_output_file(path, option, {".ply"})
    if residuals is not None:
        from metrology.jobs.outputs import check_table_path

        check_table_path(residuals, "--residuals")
    if warn is None:
        import warnings

        def warn(message):
            warnings.warn(message, stacklevel=2)

    notify(progress, 0, 3, "reading the cloud")
    read = read_cloud_checked(cloud, units=units, nonfinite="drop", hint=units is None)
    if read.n_dropped_nonfinite:
        warn(f"{cloud}: {read.n_dropped_nonfinite} of {read.n_in_file} points have NaN coordinates "
             "(missing returns of an organized scan): dropped")
    if units is None and read.units_hint is not None and read.units_hint.likely != "mm":
        warn(f"{cloud}: {read.units_hint.sentence}")
    points = read.points
    notify(progress, 1, 3, f"fitting the plane to {len(points)} points")
    try:
        fit = fit_plane_robust(points, threshold_mm=threshold_mm, seed=seed)
    except ValueError as exc:
        raise ValueError(f"{cloud}: {exc}") from None
    fit = replace(fit, source=display_name(cloud), format=fmt, read=read.to_dict())
    notify(progress, 2, 3, "writing the plane and the residual map")
    with contextlib.ExitStack() as stack:
        if out is not None:
            tmp = stack.enter_context(atomic_path(out))
            tmp.write_text(json.dumps(fit.to_dict(), indent=2) + "\n", encoding="utf-8")
        if plot is not None:
            tmp = stack.enter_context(atomic_path(plot))
            from metrology.report.datum import plot_residuals

            plot_residuals(points, fit, tmp)
        if inliers is not None or outliers is not None or residuals is not None:
            _write_points(stack, fit, points, inliers, outliers, residuals)
        if report is not None:
            from metrology.report.html import render_html, run_info
            from metrology.report.pages import plane_section

            page = render_html("Datum plane fit", run_info({"cloud": cloud}, command, seed), [plane_section(fit, points, flatness_mm)])
            tmp = stack.enter_context(atomic_path(report))
            tmp.write_text(page, encoding="utf-8")
    notify(progress, 3, 3, "done")
    return fit


def _write_points(stack, fit, points, inliers, outliers, residuals):
    """The inliers and outliers as PLY, the per-point residual table, each into a temporary file
    of ``stack`` (moved into place with the other outputs)."""
    import numpy as np

    from metrology.io.atomic import atomic_path
    from metrology.io.clouds import write_ply

    mask = fit.inliers(points)
    for path, keep, what in ((inliers, mask, "inliers"), (outliers, ~mask, "outliers")):
        if path is not None:
            write_ply(stack.enter_context(atomic_path(path)), points[keep],
                      (f"metro fit-plane {what} of {fit.source} (mm)",))
    if residuals is not None:
        from pathlib import Path

        from metrology.jobs.outputs import TABLE_WRITERS

        r = points @ fit.plane.normal + fit.plane.offset
        cols = {"x": points[:, 0], "y": points[:, 1], "z": points[:, 2], "residual_mm": r,
                "inlier": mask.astype(np.int8)}
        TABLE_WRITERS[Path(residuals).suffix.lower()](stack.enter_context(atomic_path(residuals)), cols)
