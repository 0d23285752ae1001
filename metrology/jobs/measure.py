"""The ``metro measure`` job: a hole log and a calibrated layout in; per-hole results, the fleet
summary, drift alarms and the report out."""

from __future__ import annotations

import contextlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from metrology.core.progress import ProgressFn
from metrology.jobs.measure_map import holes_collector
from metrology.jobs.measure_report import (MISFIT_SHARE, SCHEMA, CadCheck, ChartSettings, KnownSurfaces,
                                          MeasureReport, OffCad, RadiusBound, Sources)
from metrology.jobs.measure_panel import check_join, hole_surfaces, layout_panel

__all__ = ["MeasureReport", "MeasureOptions", "measure_files", "SCHEMA"]



#: the median hole's farthest spot (zero + reading x direction, TCS) may lie at most this many times the head's reach
#: (its footprint radius + its stand-off, mm) from the TCS origin. A real head's spots lie within about one reach
#: (the footprint at the stand-off, the sensors' range a few mm either side); readings in µm (x1000) put them some
#: 700 reaches out, where the curvature allowance r^2/2R swallows the misfit and _check_fit never fires (issue 51)
SPOT_REACH = 10.0
#: the reach rule's median needs this many holes with readings (fewer: not judged); ``--follow`` holds as many lines
REACH_HOLES = 5


def _spot_reach(layout, d) -> float:
    """The median hole's farthest spot from the TCS origin (mm) for readings ``d (m, n)`` mm (NaN: none)."""
    far = np.linalg.norm(layout.zero + d[:, :, None] * layout.direction, axis=2)  # (m, n) mm, TCS
    far = np.max(np.where(np.isfinite(far), far, -np.inf), axis=1)
    far = far[np.isfinite(far)]
    return float(np.median(far)) if len(far) >= REACH_HOLES else float("nan")


def _check_reach(layout, log, shown_layout) -> None:
    """Refuse (ValueError) a log whose first rows' readings (:func:`first_readings`) put the median hole's spots
    beyond :data:`SPOT_REACH` reaches of the head (readings not in mm), before anything is measured. A head whose
    reach is unknown (beams not converging on its tool axis, no range stated) is left to :func:`_check_fit`."""
    from metrology.io.holelog_sample import first_readings
    from metrology.jobs.measure_panel import footprint_mm, standoff_mm

    d = first_readings(log, [f"d_{s}" for s in layout.names])
    try:
        reach = footprint_mm(layout) + standoff_mm(layout)
    except ValueError:
        return
    if d is None or not (np.isfinite(reach) and reach > 0) or not _spot_reach(layout, d) > SPOT_REACH * reach:
        return
    far = _spot_reach(layout, d)
    unit = "look like µm" if _spot_reach(layout, d / 1000) <= SPOT_REACH * reach else "are not in mm"
    raise ValueError(f"{log.display}: the readings put the median hole's spots {far:,.0f} mm from the tool, "
                     f"{far / reach:,.0f} times the reach of the head of {shown_layout} ({reach:.3g} mm: footprint "
                     f"and stand-off): the readings {unit}: write the log's d_<sensor> columns in mm (or is this "
                     f"layout another head's?)")


def _check_fit(result, shown_layout, min_radius_mm, warn=None, warnings=None, surfaces=None) -> None:
    """Refuse (ValueError) results the data cannot support: most holes' readings disagreeing with
    one plane means the layout is not this head's (another head's file, a nominal layout on a head
    far from it, readings in other units). A partitioned output is already written: a warning."""
    rows = result.rows
    bad = result.summary.disagree
    if rows >= 20 and bad > MISFIT_SHARE * rows:
        line = (f"{shown_layout}: the readings of {bad:,} of {rows:,} holes disagree with one plane by more than a "
                f"panel of radius >= {min_radius_mm:g} mm allows: this layout does not fit the head that made the "
                f"log (another head's layout? readings not in mm? a more curved panel: --min-radius-mm)"
                if surfaces is None else
                f"{shown_layout}: the readings of {bad:,} of {rows:,} holes disagree with the panel's surface "
                f"({surfaces.source}): this layout does not fit the head that made the log (another head's layout? "
                f"a nominal layout, not its calibration? readings not in mm?), or the panel is far off its CAD "
                f"(--form-tolerance-mm states how far it may be)" + (
                    f"; {result.summary.on_convention:,} holes took the head's spin from the cell's convention (the log "
                    f"has no pose_* columns): log the robot's commanded pose" if result.summary.on_convention else ""))
        if warnings is None:
            raise ValueError(line)
        warnings.append(line)
        if warn is not None:
            warn(line)


def _digest(layout_path) -> str:
    """The layout file's SHA-256, as the certificate, the report and the QIF give it."""
    from metrology.io.names import sha256_file

    return sha256_file(layout_path)


class _Tee:
    """Batches of results into several sinks (the results file and the QIF document)."""

    def __init__(self, *sinks):
        self.sinks = sinks

    def write(self, table) -> None:
        for s in self.sinks:
            s.write(table)


def _qif_doc(qif, tolerance_deg, layout_path, layout, log_display, inputs=None):
    """The QIF 3.0 Results writer for ``--qif`` (None without it); ``inputs``: the panel's files by role."""
    if qif is None:
        return None
    from metrology import __version__
    from metrology.io.qif import QifResults

    return QifResults(qif, tolerance_deg=tolerance_deg, layout_path=layout_path, sensors=layout.names,
                      log=log_display, certificate=layout.certificate, version=__version__, inputs=inputs)


def _qif_from_output(doc, output, log) -> None:
    """Write ``doc`` from a partitioned output's files, row group by row group, in the log's order."""
    import pyarrow.parquet as pq

    with doc:
        for part in log.partitions:
            pf = pq.ParquetFile(output.target(part.relative), pre_buffer=False)
            for g in range(pf.num_row_groups):
                doc.write(pf.read_row_group(g, columns=list(QIF_COLUMNS), use_threads=False))


#: the per-hole result columns a QIF document is made from
QIF_COLUMNS = ("hole_id", "angle_deg", "U95_angle_deg", "angle_after_deg", "U95_after_deg", "status", "time")


@dataclass(frozen=True)
class MeasureOptions:
    """How ``metro measure`` runs (the CLI builds it by keyword; every field has the CLI's default).

    Attributes
    ----------
    out : path or None, per-hole results: a ``.csv``/``.parquet`` file, a folder for a partitioned
        log, or None (CSV on stdout; nothing with ``per_hole`` False)
    tolerance_deg : float, deg, the perpendicularity tolerance
    min_radius_mm : float or None, mm, the smallest panel radius (None: the layout's ``[panel]
        radius_mm``, else 500, named as an assumption)
    workers : int or None, a new Dask LocalCluster of this many worker processes
    scheduler : str or None, a running Dask scheduler (``tcp://host:port``)
    report_html : path or None, the HTML report; command : str or None, the command line it shows
    fail_on_drift : bool, a drift alarm fails the verdict
    log_display : str or None, how outputs name the log (``<stdin>``)
    batch_rows : int or None, rows per batch (None: :data:`metrology.io.holelog_reader.BATCH_ROWS`)
    chart_by_panel : bool, a new drift-chart baseline at each panel
    qif : path or None, the per-hole results also as a QIF 3.0 Results document
    dfq : path or None, the per-hole results also as a Q-DAS DFQ file (:mod:`metrology.jobs.plant`)
    plant : a results sink or None, the OPC UA server of ``--opcua`` (started), sent every hole's result
    per_hole : bool, False with no ``out``: nothing per hole written (``--json`` alone)
    panel, points : path or None, the CAD panel and the hole table (:func:`measure_files`)
    position_error_mm, form_tolerance_mm : float, mm; spin_deg : float or None, deg (with
        ``points``; None: not stated, :func:`metrology.jobs.measure_panel.hole_surfaces`)
    units : str or None, the unit of the panel file and the hole table (mm, cm, m, in; None: the
        panel's own, else mm)
    """

    out: Path | None = None
    tolerance_deg: float = 0.5
    min_radius_mm: float | None = None
    workers: int | None = None
    scheduler: str | None = None
    report_html: Path | None = None
    command: str | None = None
    fail_on_drift: bool = False
    log_display: str | None = None
    batch_rows: int | None = None
    chart_by_panel: bool = False
    qif: Path | None = None
    dfq: Path | None = None
    plant: object | None = None
    per_hole: bool = True
    panel: Path | None = None
    points: Path | None = None
    position_error_mm: float = 0.5
    form_tolerance_mm: float = 0.0
    spin_deg: float | None = None
    units: str | None = None

    @property
    def distributed(self) -> bool:
        return self.workers is not None or self.scheduler is not None


@contextlib.contextmanager
def _engine(opts: MeasureOptions):
    """The engine the options ask for, for a ``with`` block: a callable that returns it. One process;
    or Dask, whose cluster (or connection) is started in a thread as the block begins, so its start
    (0.5 s for 2 local workers) can overlap the reading and checking of the inputs (both hold the GIL
    in parts); the block's end waits for it and closes the cluster when this run started it."""
    if not opts.distributed:
        from metrology.measure.run import OneProcess

        yield OneProcess
        return
    from concurrent.futures import ThreadPoolExecutor

    from metrology.measure.fleet import DaskEngine, connect

    name = f"Dask scheduler {opts.scheduler}" if opts.scheduler else f"Dask LocalCluster, {opts.workers} worker(s)"
    opened = contextlib.ExitStack()
    with ThreadPoolExecutor(1) as starter:  # one thread opens and closes (Dask's client is bound to it)
        client = starter.submit(opened.enter_context, connect(opts.workers, opts.scheduler))
        try:
            yield lambda: DaskEngine(client.result(), name)  # a start that failed raises here, if asked for
        finally:
            starter.submit(opened.close).result()


def measure_files(log_path, layout_path, options: MeasureOptions | None = None, warn=None,
                  progress: ProgressFn | None = None) -> MeasureReport:
    """Measure every hole of ``log_path`` with ``layout_path`` as ``options`` say
    (:class:`MeasureOptions`): write ``out`` (a ``.csv`` or ``.parquet`` file, a folder for a
    partitioned log, or None: CSV on stdout) and the HTML report ``report_html``. With ``workers``
    or ``scheduler`` the partitions run on Dask. ``qif``: the per-hole results also as a QIF 3.0
    Results document (:mod:`metrology.io.qif`). With ``per_hole`` False and no ``out`` nothing per
    hole is written (``--json`` alone: the summary).

    Everything is checked before anything is written (a new Dask cluster starts meanwhile); each
    output file is written atomically. ``warn(line)`` receives the warnings (also kept in the
    report); ``progress(done, total, what)`` is called as holes are measured.

    ``panel`` (a mesh or STEP file) with ``points`` (the hole table ``hole_id,x,y,z,i,j,k``), or
    ``points`` alone: each hole's local surface is known (:mod:`metrology.measure.panel`) and its
    normal fitted with it (:mod:`metrology.measure.surface`); ``position_error_mm`` (the drill
    point's error along the surface), ``form_tolerance_mm`` (the panel's stated form tolerance
    over the footprint) and ``spin_deg`` (the head's spin about the tool axis relative to the
    panel, beyond the cell's convention) enter U95. Without them ``min_radius_mm`` bounds the
    micro-plane's curvature bias, named in the verdict as the assumption it is. The layout file may
    state the cell's panel once (:func:`layout_panel`: ``[panel]`` with ``file`` and ``points``, or
    ``points``, or ``radius_mm``), used where the options give none. ``min_radius_mm`` None: the
    layout's ``[panel] radius_mm``, else 500 mm (assumed).
    """
    o = MeasureOptions() if options is None else options
    with _engine(o) as engine:
        return _measure_files(log_path, layout_path, o, engine, warn, progress)


def _measure_files(log_path, layout_path, o: MeasureOptions, engine, warn, progress) -> MeasureReport:
    """:func:`measure_files` with the engine being started (``engine()`` returns it when it is up)."""
    from metrology.io.holelog import open_log
    from metrology.io.holelog_reader import BATCH_ROWS
    from metrology.io.holeout import PartitionedOutput, TableSink, check_out, is_file_out
    from metrology.io.layout import load_layout
    from metrology.io.names import display_name
    from metrology.measure.chart import chart_settings
    from metrology.measure.holes import Settings
    from metrology.measure.run import measure_log

    o, radius_source = _panel_options(o, layout_path)
    min_radius_mm, panel, points = o.min_radius_mm, o.panel, o.points
    _check_report_paths(o)
    layout = load_layout(layout_path)
    shown_layout = display_name(layout_path)
    warnings = _layout_warnings(layout, shown_layout)
    surfaces = None
    if panel is not None and points is None:
        raise ValueError(f"--panel {display_name(panel)}: give the hole table too (--points HOLES.csv: "
                         f"hole_id,x,y,z,i,j,k), to join the log's holes to the panel")
    log = open_log(log_path, layout.names, batch_rows=o.batch_rows or BATCH_ROWS, display=o.log_display)
    if points is not None:  # the log's commanded positions checked against the table's unit too
        surfaces = hole_surfaces(layout, panel, points, o.position_error_mm, o.form_tolerance_mm, o.spin_deg,
                                 o.units, log)
    from metrology.measure.effects import check_log

    check_log(layout, log)  # a covariate the layout's head terms need, named before any hole is measured
    log = _unread(log, layout, surfaces)
    _check_reach(layout, log, shown_layout)
    if surfaces is not None:
        check_join(log, surfaces, display_name(points))
    target = check_out(o.out, log.partitioned, o.distributed)
    settings = Settings(tolerance=float(np.radians(o.tolerance_deg)), min_radius_mm=float(min_radius_mm),
                        surfaces=surfaces)
    for w in warnings:
        if warn is not None:
            warn(w)
    output = None
    if target is not None and not is_file_out(o.out):
        output = PartitionedOutput(target, _manifest(o, layout_path, log_path))
    done = [0]

    def tick(n):
        done[0] += n
        if progress is not None:
            progress(done[0], None, f"{done[0]:,} holes measured")

    sources = Sources(log.display, shown_layout, None if o.out is None else str(o.out),
                      None if o.qif is None else str(o.qif))
    qif_doc = _qif_doc(o.qif, o.tolerance_deg, layout_path, layout, log.display,
                       {"CAD panel": panel, "hole table": points})
    from metrology.jobs.plant import dfq_sink, docs_from_output

    dfq_doc = dfq_sink(o.dfq, o.tolerance_deg, layout_path, points, surfaces, log.display)

    holes_map = None if o.report_html is None else holes_collector(surfaces, panel, points, o.units)

    def run(sink):
        """The log measured by the engine asked for, results into ``output`` (a folder) or ``sink``."""
        return measure_log(log, layout, settings, engine(), sink=sink, output=output, progress=tick,
                           by_panel=o.chart_by_panel)

    def check_fit(result, **kw):
        _check_fit(result, shown_layout, min_radius_mm, surfaces=surfaces, **kw)

    if output is not None:
        try:
            result = run(None)
        except BaseException:
            output.release()
            output.abort()  # nothing written by any run: no manifest, no folder left
            raise
        output.release()
        if output.waited_line() is not None:  # another run's lock, freed within the wait: this one resumed
            warnings.append(output.waited_line())
            if warn is not None:
                warn(output.waited_line())
    elif target is None and not o.per_hole and qif_doc is None and dfq_doc is None and o.plant is None:  # --json alone: the summary, nothing per hole
        result = run(holes_map)
        check_fit(result)
    else:
        with qif_doc or contextlib.nullcontext() as q, dfq_doc or contextlib.nullcontext() as d, \
                TableSink(target) as sink:
            table = sink if target is not None or o.per_hole else None  # --json alone: no CSV on stdout
            result = run(sink if q is None and d is None and o.plant is None and holes_map is None else
                         _Tee(*(x for x in (table, q, d, o.plant, holes_map) if x is not None)))
            check_fit(result)  # before the files appear
    if output is not None:
        check_fit(result, warn=warn, warnings=warnings)
        if qif_doc is not None:  # from the partitions' files, in the log's order, whoever wrote them
            _qif_from_output(qif_doc, output, log)
        docs_from_output((dfq_doc,), output, log, (o.plant,))
        if holes_map is not None:
            holes_map.read_output(output, log)
    report = MeasureReport(result, sources, o.tolerance_deg, min_radius_mm, layout.names,
                           layout.covariance is not None, result.engine, tuple(warnings), o.fail_on_drift,
                           ChartSettings(**chart_settings(), by_panel=o.chart_by_panel),
                           _curvature(o, result, surfaces, radius_source, shown_layout),
                           () if layout.effects is None else tuple(c.label for c in layout.effects.components),
                           None if holes_map is None else holes_map.panel_map())
    if o.report_html is not None:
        _write_report_html(o, report, log_path, layout_path)
    return report


def _unread(log, layout, surfaces):
    """``log`` with the columns this run does not read (:attr:`~metrology.io.holelog_reader.HoleLog.skip`): metro's
    numeric inputs (:data:`~metrology.io.holelog_schema.NUMERIC`; not written to the results) but the commanded pose
    with the panel known and the temperature a head term needs."""
    import dataclasses

    from metrology.io.holelog_schema import NUMERIC
    from metrology.measure.pose import POSE_COLUMNS

    need = set(POSE_COLUMNS) if surfaces is not None else set()
    if layout.effects is not None:
        need |= set(layout.effects.needs())
    return dataclasses.replace(log, skip=tuple(c for c in NUMERIC if c not in need))


def _panel_options(o: MeasureOptions, layout_path) -> tuple:
    """``o`` with the panel, the hole table and the radius bound the layout states where the options
    give none (:func:`layout_panel`; the radius 500 mm when neither does), and where the radius came
    from; ValueError for a tolerance or a radius out of range."""
    import dataclasses

    if not (0 < o.tolerance_deg < 90):
        raise ValueError(f"--tolerance-deg must be in (0, 90) deg, got {o.tolerance_deg:g}")
    stated = layout_panel(layout_path)
    radius_source = "--min-radius-mm"
    if o.panel is None and o.points is None:
        o = dataclasses.replace(o, panel=stated.get("file"), points=stated.get("points"))
    if o.min_radius_mm is None:
        from metrology.measure.holes import DEFAULT_MIN_RADIUS_MM

        o = dataclasses.replace(o, min_radius_mm=stated.get("radius_mm", DEFAULT_MIN_RADIUS_MM))
        radius_source = "layout [panel] radius_mm" if "radius_mm" in stated else "default"
    if not o.min_radius_mm > 0:
        raise ValueError(f"--min-radius-mm must be positive (inf: flat panels only), got {o.min_radius_mm:g}")
    return o, radius_source


def _check_report_paths(o: MeasureOptions) -> None:
    """The HTML report's and the QIF document's paths checked before anything is measured."""
    if o.report_html is not None:
        from metrology.report.html import check_report_path

        check_report_path(o.report_html)
    if o.qif is not None:
        from metrology.io.qif import check_qif_path

        check_qif_path(o.qif)
    if o.dfq is not None:
        from metrology.io.dfq import check_dfq_path

        check_dfq_path(o.dfq)


def _manifest(o: MeasureOptions, layout_path, log_path) -> dict:
    """What a folder output's resume manifest records of the run (paths resolved)."""
    return {"tolerance_deg": o.tolerance_deg, "min_radius_mm": o.min_radius_mm, "chart_by_panel": o.chart_by_panel,
            "panel": None if o.panel is None else str(Path(o.panel).resolve()),
            "points": None if o.points is None else str(Path(o.points).resolve()),
            "panel_terms": [o.position_error_mm, o.form_tolerance_mm, o.spin_deg], "units": o.units,
            "layout_sha256": _digest(layout_path), "log": str(Path(log_path).resolve())}


def _curvature(o: MeasureOptions, result, surfaces, radius_source: str, shown_layout: str):
    """The report's account of the panel's curvature: the radius bound (stated in the layout, or assumed), or
    the known surfaces' figures (:class:`~metrology.jobs.measure_report.KnownSurfaces`)."""
    from metrology.measure.spin import DEFAULT_SPIN_DEG

    if surfaces is None:
        return RadiusBound(o.min_radius_mm, shown_layout if radius_source == "layout [panel] radius_mm" else None,
                           result.summary.one_sensor)
    s = result.summary
    return KnownSurfaces(surfaces.source, len(surfaces.ids), o.position_error_mm, o.form_tolerance_mm,
                         DEFAULT_SPIN_DEG if o.spin_deg is None else o.spin_deg, surfaces.spin_stated,
                         s.on_convention, s.spin_free, OffCad(**s.off_cad_figures()), CadCheck(**s.vs_cad_figures()),
                         s.spin_bound, s.spin_alias)


def _write_report_html(o: MeasureOptions, report, log_path, layout_path) -> None:
    """The HTML report of the run, written atomically to ``o.report_html``."""
    from metrology.io.atomic import write_text
    from metrology.report.html import render_html, run_info
    from metrology.report.measure import measure_section

    paths = {"log": log_path, "layout": layout_path} if o.log_display is None else {"layout": layout_path}
    paths.update({"CAD panel": o.panel, "hole table": o.points})
    write_text(o.report_html, render_html("Hole measurement", run_info(paths, o.command,
                                                                       extra_versions=("pyarrow", "dask")),
                                          [measure_section(report)]))


def _layout_warnings(layout, shown_layout) -> list:
    """What the layout lacks for a full uncertainty or drift watch (ValueError: no uncertainty at all)."""
    warnings = []
    no_noise = not np.all(np.isfinite(layout.noise_mm))
    if no_noise and layout.covariance is None:
        raise ValueError(f"{shown_layout}: states neither noise_mm per sensor nor the calibration's covariance: "
                         f"no uncertainty can be given (calibrate with metro calibrate --out, or add noise_mm)")
    if layout.covariance is None:
        warnings.append(f"{shown_layout}: no [calibration] covariance: U95 carries the reading noise only, not the "
                        f"calibration's share (metro calibrate --out writes it)")
    if no_noise:
        missing = [n for n, s in zip(layout.names, layout.noise_mm) if not np.isfinite(s)]
        warnings.append(f"{shown_layout}: no noise_mm for {', '.join(missing)}: U95 carries the calibration's share "
                        f"only for them")
    if layout.n != 4:
        warnings.append(f"{shown_layout}: {layout.n} sensors: the drift watch needs exactly 4 (one redundant reading per "
                        f"hole)" + ("; 3 give no redundancy" if layout.n == 3 else ""))
    return warnings
