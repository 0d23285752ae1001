"""The ``metro measure`` job: a hole log and a calibrated layout in; per-hole results, the fleet
summary, drift alarms and the report out."""

from __future__ import annotations

import contextlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from metrology.core.progress import ProgressFn
from metrology.core.verdict import Check, Verdict

__all__ = ["MeasureReport", "measure_files", "SCHEMA"]

SCHEMA = "metro.measure/1"


@dataclass(frozen=True)
class MeasureReport:
    """What ``metro measure`` found (its JSON is :meth:`to_dict`).

    Attributes
    ----------
    result : metrology.measure.run.MeasureResult
    sources : dict, role -> display name (log, layout, out)
    tolerance_deg : float; min_radius_mm : float
    layout_names : tuple of str
    has_covariance : bool, the layout carried the calibration's covariance (propagated)
    engine : str, "one process" or the Dask cluster used
    warnings : tuple of str
    fail_on_drift : bool, whether a drift alarm fails the verdict
    """

    result: object
    sources: dict
    tolerance_deg: float
    min_radius_mm: float
    layout_names: tuple
    has_covariance: bool
    engine: str
    warnings: tuple = ()
    fail_on_drift: bool = False
    chart: dict = field(default_factory=dict)

    @property
    def counts(self) -> dict:
        return self.result.summary.counts()

    @property
    def verdict(self) -> Verdict:
        c = self.counts
        alarms = len(self.result.alarms)
        checks = [Check("drilling tolerance: holes that fail", c["fails"], 0, "holes", c["fails"] == 0),
                  Check("drilling tolerance: holes undecided (U95 straddles the tolerance)", c["undecided"], 0,
                        "holes", c["undecided"] == 0),
                  Check("drilling tolerance: holes whose drilled angle is not known (not measured after the adjustment, "
                        "the readings before it not sound: re-inspect)", self.result.summary.unknown_after, 0, "holes",
                        self.result.summary.unknown_after == 0),
                  Check("measurement: holes not measured", c["not_measured"], None, "holes", True, gate=False),
                  Check("drift watch: alarms (recalibrate)", alarms, 0, "alarms", alarms == 0, gate=self.fail_on_drift)]
        return Verdict(tuple(checks))

    def to_dict(self) -> dict:
        s = self.result.summary
        groups = [{"cell": cell, "panel": panel, "day": day, "counts": s.counts(grp), **s.figures(grp)}
                  for (cell, panel, day), grp in sorted(s.groups.items())]
        series = [{"cell": cell, "counts": s.counts(grp), **s.figures(grp)} for cell, grp in sorted(s.series.items())]
        return {
            "schema": SCHEMA,
            "sources": dict(self.sources),
            "sensors": list(self.layout_names),
            "tolerance_deg": self.tolerance_deg,
            "decision_rule": "ISO 14253-1: conforms if angle + U95 <= tolerance, fails if angle - U95 > tolerance",
            "judged": {"after_adjustment": s.judged_after, "before_adjustment": s.judged_before},
            "uncertainty": {"reading_noise": True, "calibration_covariance": self.has_covariance, "coverage": 0.95},
            "min_radius_mm": self.min_radius_mm,
            "engine": self.engine,
            "holes": self.result.rows,
            "partitions": self.result.partitions,
            "partitions_written": self.result.written,
            "counts": self.counts,
            "counts_detail": {"unknown_after": s.unknown_after},
            "fleet": s.figures(s.total()),
            "cells": series,
            "groups": groups,
            "drift": {"chart": dict(self.chart), "cells_charted": sorted(self.result.watch.charts),
                      "alarms": [a.to_dict() for a in self.result.alarms]},
            "worst": list(s.worst),
            "warnings": list(self.warnings),
            "verdict": self.verdict.to_dict(),
        }


#: a log in which more than this share of holes have readings that disagree does not fit the layout
MISFIT_SHARE = 0.5


def _check_fit(result, shown_layout, min_radius_mm, warn=None, warnings=None) -> None:
    """Refuse (ValueError) results the data cannot support: most holes' readings disagreeing with
    one plane means the layout is not this head's (another head's file, a nominal layout on a head
    far from it, readings in other units). A partitioned output is already written: a warning."""
    rows = result.rows
    bad = result.summary.disagree
    if rows >= 20 and bad > MISFIT_SHARE * rows:
        line = (f"{shown_layout}: the readings of {bad:,} of {rows:,} holes disagree with one plane by more than a "
                f"panel of radius >= {min_radius_mm:g} mm allows: this layout does not fit the head that made the "
                f"log (another head's layout? readings not in mm? a more curved panel: --min-radius-mm)")
        if warnings is None:
            raise ValueError(line)
        warnings.append(line)
        if warn is not None:
            warn(line)


def _digest(layout) -> str:
    import hashlib

    from metrology.io.layout import layout_to_toml

    return hashlib.sha256(layout_to_toml(layout).encode()).hexdigest()


class _Tee:
    """Batches of results into several sinks (the results file and the QIF document)."""

    def __init__(self, *sinks):
        self.sinks = sinks

    def write(self, table) -> None:
        for s in self.sinks:
            s.write(table)


def _qif_doc(qif, tolerance_deg, layout_path, layout, log_display):
    """The QIF 3.0 Results writer for ``--qif`` (None without it)."""
    if qif is None:
        return None
    from metrology import __version__
    from metrology.io.qif import QifResults

    return QifResults(qif, tolerance_deg=tolerance_deg, layout_path=layout_path, sensors=layout.names,
                      log=log_display, certificate=layout.certificate, version=__version__)


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


def measure_files(log_path, layout_path, out=None, tolerance_deg: float = 0.5, min_radius_mm: float = 500.0,
                  workers: int | None = None, scheduler: str | None = None, report_html=None, command=None,
                  warn=None, progress: ProgressFn | None = None, fail_on_drift: bool = False,
                  log_display: str | None = None, batch_rows: int | None = None,
                  chart_by_panel: bool = False, qif=None, per_hole: bool = True) -> MeasureReport:
    """Measure every hole of ``log_path`` with ``layout_path``; write ``out`` (a ``.csv`` or
    ``.parquet`` file, a folder for a partitioned log, or None: CSV on stdout) and the HTML
    report ``report_html``. With ``workers`` or ``scheduler`` the partitions run on Dask. ``qif``:
    the per-hole results also as a QIF 3.0 Results document (:mod:`metrology.io.qif`). With
    ``per_hole`` False and no ``out`` nothing per hole is written (``--json`` alone: the summary).

    Everything is checked before anything is written; each output file is written atomically.
    ``warn(line)`` receives the warnings (also kept in the report); ``progress(done, total, what)``
    is called as holes are measured.
    """
    from metrology.io.holelog import BATCH_ROWS, open_log
    from metrology.io.holeout import PartitionedOutput, TableSink, check_out, is_file_out
    from metrology.io.layout import load_layout
    from metrology.io.names import display_name
    from metrology.measure.chart import chart_settings
    from metrology.measure.holes import Settings

    if not (0 < tolerance_deg < 90):
        raise ValueError(f"--tolerance-deg must be in (0, 90) deg, got {tolerance_deg:g}")
    if not min_radius_mm > 0:
        raise ValueError(f"--min-radius-mm must be positive (inf: flat panels only), got {min_radius_mm:g}")
    if report_html is not None:
        from metrology.report.html import check_report_path

        check_report_path(report_html)
    if qif is not None:
        from metrology.io.qif import check_qif_path

        check_qif_path(qif)
    layout = load_layout(layout_path)
    shown_layout = display_name(layout_path)
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
    log = open_log(log_path, layout.names, batch_rows=batch_rows or BATCH_ROWS, display=log_display)
    distributed = workers is not None or scheduler is not None
    target = check_out(out, log.partitioned, distributed)
    settings = Settings(tolerance=float(np.radians(tolerance_deg)), min_radius_mm=float(min_radius_mm))
    for w in warnings:
        if warn is not None:
            warn(w)
    output = None
    if target is not None and not is_file_out(out):
        output = PartitionedOutput(target, {"tolerance_deg": tolerance_deg, "min_radius_mm": min_radius_mm,
                                            "chart_by_panel": chart_by_panel,
                                            "layout_sha256": _digest(layout), "log": str(Path(log_path).resolve())})
    total = None
    done = [0]

    def tick(n):
        done[0] += n
        if progress is not None:
            progress(done[0], total, f"{done[0]:,} holes measured")

    sources = {"log": log.display, "layout": shown_layout, "out": None if out is None else str(out)}
    if qif is not None:
        sources["qif"] = str(qif)
    qif_doc = _qif_doc(qif, tolerance_deg, layout_path, layout, log.display)

    def run(sink):
        """The log measured by the engine asked for, results into ``output`` (a folder) or ``sink``."""
        if distributed:
            from metrology.measure.fleet import connect, measure_log_dask

            client = connect(workers, scheduler)
            try:
                # a single Parquet file: its row groups are the tasks (a CSV file is one task)
                result = measure_log_dask(client, log if output is not None else log.by_row_group(), layout, settings,
                                          output, progress=tick, by_panel=chart_by_panel, sink=sink)
            finally:
                cluster = getattr(client, "cluster", None)
                client.close()
                if cluster is not None and scheduler is None:
                    cluster.close()
            return result, (f"Dask scheduler {scheduler}" if scheduler else f"Dask LocalCluster, {workers} worker(s)")
        from metrology.measure.run import measure_log, tune_allocator

        tune_allocator()
        return measure_log(log, layout, settings, sink=sink, output=output, progress=tick,
                           by_panel=chart_by_panel), "one process"

    if output is not None:
        try:
            result, engine = run(None)
        except BaseException:
            output.release()
            output.abort()  # nothing written by any run: no manifest, no folder left
            raise
        output.release()
    elif target is None and not per_hole and qif_doc is None:  # --json alone: the summary, nothing per hole
        result, engine = run(None)
        _check_fit(result, shown_layout, min_radius_mm)
    else:
        with qif_doc or contextlib.nullcontext() as q, TableSink(target) as sink:
            result, engine = run(sink if q is None else _Tee(sink, q))
            _check_fit(result, shown_layout, min_radius_mm)  # before the files appear
    if output is not None:
        _check_fit(result, shown_layout, min_radius_mm, warn=warn, warnings=warnings)
        if qif_doc is not None:  # from the partitions' files, in the log's order, whoever wrote them
            _qif_from_output(qif_doc, output, log)
    report = MeasureReport(result, sources, tolerance_deg, min_radius_mm, layout.names, layout.covariance is not None,
                           engine, tuple(warnings), fail_on_drift, {**chart_settings(), "by_panel": chart_by_panel})
    if report_html is not None:
        from metrology.io.atomic import write_text
        from metrology.report.html import render_html, run_info
        from metrology.report.measure import measure_section

        paths = {"log": log_path, "layout": layout_path} if log_display is None else {"layout": layout_path}
        write_text(report_html, render_html("Hole measurement", run_info(paths, command, extra_versions=("pyarrow", "dask")),
                                            [measure_section(report)]))
    return report
