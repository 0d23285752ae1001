"""The ``metro calibrate`` and ``metro validate`` jobs: files in, calibrated layout, report and figures out."""

from __future__ import annotations

from metrology.calibration.calibrate import CalibrationReport, DEFAULT_METHOD, calibrate_dataset
from metrology.calibration.validation import ValidationReport, validate
from metrology.core.progress import ProgressFn, notify
from metrology.core.tolerances import DRILLING_TOLERANCE_DEG
from metrology.io.names import display_name


def load_checked(export_path, plane_path, layout_path, quaternion_order="wxyz", position_units="mm", no_reading=None,
                 warn=None, allow_gross_readings=False):
    """:func:`~metrology.calibration.dataset.load_dataset`, then refuse a gross mismatch naming the
    likely mistake (:func:`metrology.calibration.sanity.check_dataset`; ``allow_gross_readings``:
    not data gross only through a few gross readings, which ``diagnose`` flags). ``warn(line)``
    is called with the count of dropped "no reading" codes, if any."""
    from metrology.calibration.dataset import load_dataset
    from metrology.calibration.sanity import check_dataset

    dataset = load_dataset(export_path, plane_path, layout_path, quaternion_order, position_units, no_reading, warn)
    check_dataset(dataset, str(export_path), quaternion_order, position_units, allow_gross_readings)
    if warn is not None and dataset.dropped:
        warn(f"{export_path}: {dataset.no_reading_summary()}")
    return dataset


def calibrate_files(export_path, plane_path, layout_path, method: str = DEFAULT_METHOD, target=None, out=None,
                    plot_dir=None, quaternion_order="wxyz", position_units="mm", no_reading=None,
                    warn=None, report_html=None, command=None, progress: ProgressFn | None = None,
                    **kwargs) -> CalibrationReport:
    """Load and cross-check the three files, calibrate, and write the requested outputs.

    ``quaternion_order``, ``position_units`` and ``no_reading`` say how to read the export
    (:func:`~metrology.calibration.dataset.load_dataset`); data that do not fit the model by
    orders of magnitude are refused, naming the likely mistake, before anything is written.

    Nothing is written unless the calibration succeeds; each file is written atomically
    (the figures first, then the calibrated layout ``out``, in the schema of the nominal
    with ``zero_stderr_mm`` and ``direction_stderr_deg`` added, then the HTML report
    ``report_html`` naming ``command``, None: this process's command line).

    ``progress(done, total, what)`` is called before each step (read, calibrate, figures, write).
    """
    from metrology.io.layout import save_layout

    _check_report(report_html)
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
    page = None
    if report_html is not None:  # rendered before anything is written: all or nothing
        from metrology.report.html import render_html, run_info
        from metrology.report.pages import calibration_section

        page = render_html("Sensor calibration", run_info(paths, command), [calibration_section(report)])
    if plot_dir is not None:
        from metrology.report.calibration import write_calibration_plots

        notify(progress, done, total, "drawing the figures")
        write_calibration_plots(report, plot_dir)
        done += 1
    if out is not None:
        notify(progress, done, total, "writing the calibrated layout")
        rms = ", ".join(f"{n} {r * 1e3:.1f} um" for n, r in zip(report.layout.names, report.calibration.residual_rms))
        save_layout(report.layout, out,
                    f"Calibrated by metro calibrate --method {method}\n"
                    f"export {sources['export']}, datum {sources['plane']}, nominal {sources['layout']}\n"
                    f"{dataset.export.n_poses} poses; residual RMS {rms}\n"
                    "zero_stderr_mm: 1 sigma of the zero point (mm, TCS x y z); direction_stderr_deg: 1 sigma\n"
                    "of the beam tilt about the chart axes e1, e2 of the nominal direction (deg)")
    if page is not None:
        from metrology.io.atomic import write_text

        write_text(report_html, page)
    notify(progress, total, total, "done")
    return report


def _check_report(path):
    if path is not None:
        from metrology.report.html import check_report_path

        check_report_path(path)


def validate_files(export_path, plane_path, layout_path, layout_before_path=None, plot=None, quaternion_order="wxyz",
                   position_units="mm", no_reading=None, warn=None, tolerance_deg=DRILLING_TOLERANCE_DEG,
                   report_html=None, command=None) -> ValidationReport:
    """Validate ``layout_path`` (and ``layout_before_path``, first, if given) on an export.

    The layouts are reported under the labels ``layout_before`` and ``layout``; ``plot``
    writes the deviation per pose (atomically; the format from the suffix) with the
    tolerance ``tolerance_deg`` drawn; ``report_html`` the HTML report judging the
    validated layout against it.
    """
    from metrology.io.layout import load_layout

    _check_report(report_html)
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
    if page is not None:
        from metrology.io.atomic import write_text

        write_text(report_html, page)
    return report
