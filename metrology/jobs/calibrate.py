"""The ``metro calibrate`` and ``metro validate`` jobs: files in, calibrated layout, report and figures out."""

from __future__ import annotations

from metrology.calibration.calibrate import CalibrationReport, DEFAULT_METHOD, calibrate_dataset
from metrology.calibration.sanity import load_checked
from metrology.calibration.validation import ValidationReport, validate
from metrology.core.progress import ProgressFn, notify
from metrology.core.tolerances import DRILLING_TOLERANCE_DEG
from metrology.io.names import display_name


def calibrate_files(export_path, plane_path, layout_path, method: str = DEFAULT_METHOD, target=None, out=None,
                    plot_dir=None, quaternion_order="wxyz", position_units="mm", no_reading=None,
                    warn=None, report_html=None, command=None, progress: ProgressFn | None = None,
                    meta=None, qif=None, dfq=None, **kwargs) -> CalibrationReport:
    """Load and cross-check the three files, calibrate, and write the requested outputs.

    ``quaternion_order``, ``position_units`` and ``no_reading`` say how to read the export
    (:func:`~metrology.calibration.dataset.load_dataset`); data that do not fit the model by
    orders of magnitude are refused, naming the likely mistake, before anything is written.

    Nothing is written unless the calibration succeeds; each file is written atomically
    (the figures first, then the calibrated layout ``out``, in the schema of the nominal
    with ``zero_stderr_mm`` and ``direction_stderr_deg`` added, then the HTML report
    ``report_html`` naming ``command``, None: this process's command line).

    ``progress(done, total, what)`` is called before each step (read, calibrate, figures, write).

    ``qif``: the calibrated head also as a QIF 3.0 measurement device
    (:func:`metrology.io.qif.write_device_document`), written after ``out``; ``dfq``: the calibrated
    parameters as a Q-DAS DFQ file (:func:`metrology.io.dfq.write_calibration_dfq`).

    ``meta`` (dict of str -> str): the certificate's header fields, written into the calibrated
    layout's ``[certificate]`` table. The report's ``certificate`` is made from the calibrated
    TOML's text read back (:mod:`metrology.report.certificate`), so the two hold the same values.
    """
    from dataclasses import replace

    from metrology.io.atomic import write_text
    from metrology.io.layout import layout_to_toml

    _check_report(report_html)
    if qif is not None:
        from metrology.io.qif import check_qif_path

        check_qif_path(qif)
    if dfq is not None:
        from metrology.io.dfq import check_dfq_path

        check_dfq_path(dfq)
    if plot_dir is not None:
        from metrology.report.calibration import check_plot_target

        check_plot_target(plot_dir)
    total = 2 + (plot_dir is not None) + (out is not None)
    notify(progress, 0, total, "reading the export, datum and layout")
    dataset = load_checked(export_path, plane_path, layout_path, quaternion_order, position_units, no_reading, warn)
    paths = {"export": export_path, "plane": plane_path, "layout": layout_path}
    sources = {k: display_name(v) for k, v in paths.items()}
    notify(progress, 1, total, f"calibrating ({method}, {dataset.export.n_poses} poses)")
    report = calibrate_dataset(dataset, method, sources=sources, target=target, **kwargs)
    done = 2
    header = (f"Calibrated by metro calibrate --method {method}\n"
              f"export {sources['export']}, datum {sources['plane']}, nominal {sources['layout']}\n"
              f"{dataset.export.n_poses} poses; residual RMS "
              + ", ".join(f"{n} {r * 1e3:.1f} µm" for n, r in zip(report.layout.names, report.calibration.residual_rms))
              + "\nzero_stderr_mm: 1 sigma of the zero point (mm, TCS x y z); direction_stderr_deg: 1 sigma\n"
              f"of the beam tilt about the chart axes e1, e2 of the {_chart(report.layout)} direction (deg)")
    # the certificate states the datum's share of U (or that the plane was taken as exact)
    text = layout_to_toml(replace(_tilts_in_covariance_chart(report.layout),
                                  certificate={"datum": report.datum_statement(), **dict(meta or {})}), header)
    report = replace(report, certificate=_certificate(report, text, out))
    page = None
    if report_html is not None:  # rendered before anything is written: all or nothing
        from metrology.report.certificate import certificate_section
        from metrology.report.html import render_html, run_info
        from metrology.report.pages import calibration_section

        page = render_html("Sensor calibration", run_info(paths, command),
                           [certificate_section(report.certificate), calibration_section(report)])
    if plot_dir is not None:
        from metrology.report.calibration import write_calibration_plots

        notify(progress, done, total, "drawing the figures")
        write_calibration_plots(report, plot_dir)
        done += 1
    if out is not None:
        notify(progress, done, total, "writing the calibrated layout")
        write_text(out, text)
    if qif is not None:
        import hashlib

        from metrology import __version__
        from metrology.io.qif import write_device_document

        write_device_document(qif, replace(report.layout, certificate=dict(meta or {})),
                              hashlib.sha256(text.encode()).hexdigest(), None if out is None else display_name(out).replace("\\", "/").rsplit("/", 1)[-1],
                              __version__, method, dataset.export.n_poses)
    if dfq is not None:
        import time

        from metrology.io.dfq import write_calibration_dfq

        write_calibration_dfq(dfq, text, dataset.layout, time.time())
    if page is not None:
        write_text(report_html, page)
    notify(progress, total, total, "done")
    return report


def _chart(layout) -> str:
    return "calibrated" if layout.covariance is not None else "nominal"


def _tilts_in_covariance_chart(layout):
    """``layout`` with ``direction_stderr_deg`` the 1 sigma of its covariance's tilt blocks: the chart of the
    calibrated direction, the certificate's and ``metro measure``'s (the fit's own is the nominal's)."""
    from dataclasses import replace

    import numpy as np

    if layout.covariance is None or layout.direction_stderr_deg is None:
        return layout
    var = np.diag(layout.covariance).reshape(layout.n, 5)[:, 3:]
    return replace(layout, direction_stderr_deg=np.degrees(np.sqrt(np.maximum(var, 0.0))))


def _certificate(report, text, out):
    """The certificate of the calibrated TOML ``text`` (to be written to ``out``, or not written),
    its numbers read back from the text itself."""
    import tempfile
    from pathlib import Path

    import numpy as np

    from metrology.io.layout import load_layout
    from metrology.report.certificate import certificate_from_toml
    from metrology.report.html import written

    with tempfile.TemporaryDirectory(prefix="metro-cert-") as tmp:
        path = Path(tmp) / "calibrated.toml"
        path.write_text(text, encoding="utf-8")
        back = load_layout(path)
    d = report.dataset.obs.d
    standoff = (float(np.nanmin(d)), float(np.nanmax(d)))
    tilt = max((ident.tilt_max_deg for ident in report.identifiability), default=float("nan"))
    return certificate_from_toml(text, back, None if out is None else display_name(out), report.calibration.method,
                                 report.dataset.export.n_poses, standoff, tilt, written())


def _check_report(path):
    if path is not None:
        from metrology.report.html import check_report_path

        check_report_path(path)


def validate_files(export_path, plane_path, layout_path, layout_before_path=None, plot=None, quaternion_order="wxyz",
                   position_units="mm", no_reading=None, warn=None, tolerance_deg=DRILLING_TOLERANCE_DEG,
                   report_html=None, command=None, per_pose=None) -> ValidationReport:
    """Validate ``layout_path`` (and ``layout_before_path``, first, if given) on an export.

    The layouts are reported under the labels ``layout_before`` and ``layout``; ``plot``
    writes the deviation per pose (atomically; the format from the suffix) with the
    tolerance ``tolerance_deg`` drawn; ``report_html`` the HTML report judging the
    validated layout against it; ``per_pose`` a CSV of each pose: ``pose_id``, ``n_readings``,
    ``deviation_deg`` of the validated layout (and ``deviation_deg_before``), ``within_tolerance``
    (1/0, empty where the pose has no normal).
    """
    from metrology.io.layout import load_layout

    _check_report(report_html)
    if per_pose is not None:
        from metrology.jobs.outputs import check_table_path

        check_table_path(per_pose, "--per-pose", (".csv",))
    dataset = load_checked(export_path, plane_path, layout_path, quaternion_order, position_units, no_reading, warn)
    layouts = {}
    paths = {"export": export_path, "plane": plane_path}
    if layout_before_path is not None:
        layouts["layout_before"] = load_layout(layout_before_path)
        paths["layout_before"] = layout_before_path
    layouts["layout"] = dataset.layout
    paths["layout"] = layout_path
    report = validate(dataset, layouts, {k: display_name(v) for k, v in paths.items()})
    page = None
    if report_html is not None:  # rendered before anything is written: all or nothing
        from metrology.report.html import render_html, run_info
        from metrology.report.pages import validation_section

        page = render_html("Validation", run_info(paths, command), [validation_section(report, tolerance_deg)])
    if plot is not None:
        from metrology.report.validation import plot_validation

        plot_validation(report, plot, tolerance_deg)
    if per_pose is not None:
        _write_per_pose(report, per_pose, tolerance_deg)
    if page is not None:
        from metrology.io.atomic import write_text

        write_text(report_html, page)
    return report


def _write_per_pose(report: ValidationReport, path, tolerance_deg: float) -> None:
    import numpy as np

    from metrology.jobs.outputs import write_table

    cols = {"pose_id": list(report.pose_id), "n_readings": report.n_readings}
    for k, label in enumerate(report.labels):
        cols["deviation_deg" if label == "layout" else f"deviation_deg_{label.replace('layout_', '')}"] = \
            np.rad2deg(report.deviation[k])
    dev = np.rad2deg(report.deviation[-1])
    cols["within_tolerance"] = [("" if not np.isfinite(d) else int(d <= tolerance_deg)) for d in dev]
    write_table(path, cols)
