"""The ``metro normals`` job: files in (panel, layout, points), files out (summary, per-point table, map)."""

from __future__ import annotations

import math
import numpy as np
from metrology.core.progress import notify
from metrology.core.sphere import SPHERE_PRIOR_RADIUS_MM
from metrology.panel.attitude import MotionError, STATUS
from metrology.panel.edges import footprint_radius
from metrology.panel.head import default_standoff
from metrology.panel.mesh import load_panel
from metrology.panel.points import grid_points, read_points
from metrology.panel.rays import RayCaster
from metrology.panel.run import run_normals
from metrology.report.normals import per_point_text, plot_error_map, summarize


def normals_job(panel_path, layout_path, *, points_path=None, grid_mm=None, tilt_deg=1.0, standoff_mm=None,
                noise_mm=None, seed=0, tolerance_deg=0.5, engine="auto", out_path=None, plot_path=None,
                true_layout_path=None, motion_repeat_deg=0.02, motion_scale=0.03, motion_position_mm=0.05,
                prior_radius_mm=SPHERE_PRIOR_RADIUS_MM, loop=True, units=None, footprint_mm=None,
                on_warning=None, report=None, command=None, progress=None, beams="facets") -> dict:
    """Everything ``metro normals`` does: load, measure, summarise, write (all or nothing).

    Degrees appear only here, at the edge. Output files are written only after every
    point has been computed (each atomically); a fatal error writes nothing. ``report``: one
    self-contained HTML report naming ``command`` (None: this process's command line).
    ``progress(done, total, what)``: at each of 6 stages (load, the 4 of
    :func:`~metrology.panel.run.run_normals`, write).

    ``units`` (``mm``, ``cm``, ``m``, ``in``) overrides the panel file's unit
    (:func:`load_panel`). ``on_warning(line)`` is called with each warning about the panel
    (units, repairs) as soon as it is loaded, before anything can fail; a run in which no
    point can be measured repeats the unit warning in its error.

    Returns
    -------
    dict: the :func:`summarize` summary plus ``warnings`` (list of str), ``points`` (how
    many given) and ``grid_dropped`` (grid nodes whose footprint would straddle an edge)
    """
    from metrology.io.layout import load_layout

    if (points_path is None) == (grid_mm is None):
        raise ValueError("give exactly one of --points FILE or --grid SPACING_MM")
    for name, v in (("tilt", tilt_deg), ("tolerance", tolerance_deg), ("motion repeat", motion_repeat_deg)):
        if not (math.isfinite(v) and v >= 0):
            raise ValueError(f"{name} must be a finite angle >= 0 deg, got {v}")
    out_fmt = None
    if out_path is not None:
        out_fmt = str(out_path).lower().rsplit(".", 1)[-1]
        if out_fmt not in ("csv", "json"):
            raise ValueError(f"{out_path}: the per-point output must end in .csv or .json")
    if plot_path is not None and not str(plot_path).lower().endswith(".png"):
        raise ValueError(f"{plot_path}: the plot must be a .png file")
    if report is not None:
        from metrology.report.html import check_report_path

        check_report_path(report)
    notify(progress, 0, 6, "loading the panel and building its ray scene")
    layout = load_layout(layout_path)
    layout_true = load_layout(true_layout_path) if true_layout_path is not None else None
    from metrology.panel.head_terms import check_terms

    for lay, src in ((layout, layout_path), (layout_true, true_layout_path)):
        check_terms(lay, src)  # a term needing a covariate normals lacks (the temperature) is refused
    offsets = _true_offsets(layout if layout_true is None else layout_true)
    panel = load_panel(panel_path, units)
    for w in panel.warnings:
        if on_warning is not None:
            on_warning(w)
    caster = RayCaster(panel.mesh, engine)
    if footprint_mm is not None and not (math.isfinite(footprint_mm) and footprint_mm >= 0):
        raise ValueError(f"footprint must be a finite number of mm >= 0, got {footprint_mm}")
    foot = footprint_mm
    if foot is None and grid_mm is not None:
        standoff = default_standoff(layout) if standoff_mm is None else float(standoff_mm)
        foot = footprint_radius(layout, standoff)
    # an error repeats the unit doubt in full when no one was told it (no on_warning, e.g. under
    # -q); told once already, it is not printed a second time
    unit_hint = [] if panel.unit_warning is None else [panel.unit_warning] if on_warning is None else \
        ["the panel's unit is in doubt, see the warning above: give --units"]
    try:
        drill, dropped = (read_points(points_path), 0) if points_path is not None else \
            grid_points(panel, float(grid_mm), caster, footprint_mm=foot, with_dropped=True)
    except ValueError as exc:
        raise ValueError(str(exc) + "".join(f" ({w})" for w in unit_hint)) from None
    rng = np.random.default_rng(seed)
    motion = MotionError(math.radians(motion_repeat_deg), motion_scale, motion_position_mm)
    run = run_normals(panel, layout, drill, rng, tilt=math.radians(tilt_deg), standoff=standoff_mm, noise=noise_mm,
                      tolerance=math.radians(tolerance_deg), motion=motion, layout_true=layout_true, loop=loop,
                      caster=caster, prior_radius_mm=prior_radius_mm, footprint_mm=foot, beams=beams,
                      reading_offsets=offsets,
                      progress=None if progress is None else lambda d, n, what: progress(1 + d, 6, what))
    if not np.any(run.status == "ok"):
        counts = ", ".join(f"{int(np.sum(run.status == k))} {STATUS[k]}" for k in STATUS if k != "ok" and np.any(run.status == k))
        where = points_path if points_path is not None else f"grid {grid_mm} mm"
        raise ValueError(f"{where}: no drilling point could be measured ({counts})"
                         + "".join(f" ({w})" for w in unit_hint))
    notify(progress, 5, 6, "summary, table and map")
    summary = summarize(run)
    summary["warnings"] = list(panel.warnings)
    summary["points"] = len(run.labels)
    summary["grid_dropped"] = dropped
    text = per_point_text(run, out_fmt) if out_fmt else None
    png = plot_error_map(run, tolerance_deg) if plot_path is not None else None
    page = None
    if report is not None:
        from metrology.report.html import render_html, run_info
        from metrology.report.normals import error_map_figure
        from metrology.report.pages import normals_section

        inputs = {"panel": panel_path, "layout": layout_path, "points": points_path, "true layout": true_layout_path}
        page = render_html("Normals on a panel", run_info(inputs, command, seed),
                           [normals_section(summary, error_map_figure(run, tolerance_deg), tolerance_deg)])
    from metrology.io.atomic import atomic_path, write_text

    if text is not None:
        write_text(out_path, text)
    if png is not None and plot_path is not None:
        with atomic_path(plot_path) as tmp:
            tmp.write_bytes(png)
    if page is not None:
        write_text(report, page)
    notify(progress, 6, 6, "done")
    return summary


def _true_offsets(layout_true):
    """The true head's terms as the forward simulator's physics (:mod:`metrology.sim.head_terms`): a callable
    ``(d_true (m, n) mm, incidence (m, n) rad) -> (m, n) mm``, or None without terms."""
    from metrology.sim.head_terms import properties_from_terms

    props = properties_from_terms(layout_true)
    if props is None:
        return None
    return lambda d, angle: props.offsets(d, angle, None)
