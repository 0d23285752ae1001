"""``metro diagnose``'s file job: the three files of a run in, a :class:`~metrology.diagnosis.Diagnosis` out."""

from __future__ import annotations

from dataclasses import replace

from metrology.diagnosis.decide import Diagnosis, diagnose

__all__ = ["diagnose_files", "extend_files", "diagnose_report", "check_report_target"]


def diagnose_files(export_path, plane_path, layout_path, quaternion_order="wxyz", position_units="mm", no_reading=None,
                   warn=None, **kw) -> Diagnosis:
    """:func:`diagnose` on the three files of a run, read and screened as for ``metro calibrate``
    (:func:`metrology.calibration.sanity.load_checked`: a gross mismatch is refused, naming the mistake),
    except that a few gross readings pass: finding them is a diagnosis (``outliers``)."""
    from metrology.calibration.sanity import load_checked

    ds = load_checked(export_path, plane_path, layout_path, quaternion_order, position_units, no_reading, warn,
                      allow_gross_readings=True)
    return diagnose(_plain(ds), **kw)


def _plain(ds):
    """``ds`` as the simple model should see it: a layout's head terms removed from the readings
    (what they explain is not named again: :func:`metrology.diagnosis.layout_out.terms_removed`)."""
    if ds.layout.effects is None:
        return ds
    from metrology.diagnosis.layout_out import terms_removed

    return terms_removed(ds)


def extend_files(export_path, plane_path, layout_path, out_path, quaternion_order="wxyz", position_units="mm",
                 no_reading=None, warn=None, **kw) -> tuple:
    """``metro diagnose --out``: :func:`diagnose_files`, then the layout refitted with the head terms
    named (and those ``layout_path`` carries) written to ``out_path`` atomically:
    ``(Diagnosis, ExtendedLayout)`` (:mod:`metrology.diagnosis.layout_out`)."""
    from metrology.calibration.sanity import load_checked
    from metrology.diagnosis.layout_out import extend_layout
    from metrology.io.layout import save_layout

    ds = load_checked(export_path, plane_path, layout_path, quaternion_order, position_units, no_reading, warn,
                      allow_gross_readings=True)
    diag = diagnose(_plain(ds), **kw)
    ext = extend_layout(replace(ds, layout=replace(ds.layout, effects=None)), diag, ds.layout.effects)
    save_layout(ext.layout, out_path, header=f"metro diagnose --out: the layout of {export_path} refitted with the "
                                             f"head terms named ({', '.join(ext.written) or 'none'})")
    return diag, ext



def check_report_target(report) -> None:
    """Refuse an HTML report path that cannot be written, before the diagnosis runs."""
    from pathlib import Path

    from metrology.report.html import REPORT_SUFFIXES, check_report_path

    if Path(report).suffix.lower() in REPORT_SUFFIXES:
        check_report_path(report)


def diagnose_report(diag: Diagnosis, report, sources: dict, command=None, seed=None) -> list:
    """Write ``diag``'s report: ``report`` ending in ``.html``/``.htm`` is one self-contained HTML
    file (:mod:`metrology.report.html`); any other path a directory of residual PNGs (created if
    missing), as before. Returns the files written."""
    from pathlib import Path

    from metrology.report.html import REPORT_SUFFIXES

    if Path(report).suffix.lower() in REPORT_SUFFIXES:
        from metrology.report.html import check_report_path, run_info, write_report
        from metrology.report.pages import diagnosis_section

        check_report_path(report)
        write_report(report, "Diagnosis", run_info(sources, command, seed), [diagnosis_section(diag)])
        return [str(report)]
    from metrology.report.diagnose import plot_report

    return plot_report(diag, report)
