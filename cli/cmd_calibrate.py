"""``metro calibrate`` and ``metro validate``: sensor calibration from measured files."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from ._common import (JSON_HELP, NO_READING_HELP, POSITION_HELP, QUATERNION_HELP, REPORT_HELP, echo, echo_json, fail,
                      guarded, invocation, progress_bar, warn)
from ._stdin import plane_suffix, stdin_files

STDIN = " ('-' for stdin)"

METHODS = ("lsq", "iekf", "ekf", "ekf_paper", "method1")


def _check_out_dir(path: Optional[Path], what: str) -> None:
    """Fail before any work when an output's directory does not exist (nothing written)."""
    if path is not None and not Path(path).resolve().parent.is_dir():
        fail(f"{what} {path}: directory {Path(path).parent} does not exist")


def register(app: typer.Typer) -> None:
    @app.command("calibrate")
    @guarded
    def calibrate_cmd(
        ctx: typer.Context,
        export: Path = typer.Argument(..., help="Tracker export CSV (pose_id,x,y,z,qw,qx,qy,qz,d_<sensor>,...)" + STDIN),
        plane: Path = typer.Option(..., "--plane", help="Datum: fit-plane JSON, or a tracker cloud of the datum" + STDIN),
        layout: Path = typer.Option(..., "--layout", help="Nominal sensor layout TOML" + STDIN),
        method: str = typer.Option("lsq", "--method", help=f"Estimator: {', '.join(METHODS)}."),
        json_out: bool = typer.Option(False, "--json", help=JSON_HELP),
        out: Optional[Path] = typer.Option(None, "--out", help="Write the calibrated layout TOML here."),
        plot: Optional[Path] = typer.Option(None, "--plot", help="Convergence and residual figures: a .pdf file (a "
                                            "page each) or a directory (PNGs)."),
        report_html: Optional[Path] = typer.Option(None, "--report", help=REPORT_HELP),
        target_mm: float = typer.Option(0.05, "--target-mm", help="Wanted 1-sigma of the zero points, mm."),
        target_deg: float = typer.Option(0.05, "--target-deg", help="Wanted 1-sigma of the beam tilts, deg."),
        quaternion_order: str = typer.Option("wxyz", "--quaternion-order", help=QUATERNION_HELP),
        position_units: str = typer.Option("mm", "--position-units", help=POSITION_HELP),
        no_reading: Optional[float] = typer.Option(None, "--no-reading", help=NO_READING_HELP),
    ) -> None:
        """Calibrate the normal sensors from a tracker export, the datum and the nominal layout."""
        if method not in METHODS:
            fail(f"--method {method!r}: expected one of {', '.join(METHODS)}")
        if not (target_mm > 0 and target_deg > 0):
            fail(f"--target-mm and --target-deg must be positive, got {target_mm:g} and {target_deg:g}")
        _check_out_dir(out, "--out")
        import math

        from metrology.jobs.calibrate import calibrate_files
        from metrology.report.calibration import calibration_text, calibration_warnings

        with stdin_files(("EXPORT", export, ".csv"), ("--plane", plane, plane_suffix),
                         ("--layout", layout, ".toml")) as (export, plane, layout), progress_bar("calibrate") as progress:
            report = calibrate_files(export, plane, layout, method, target=(target_mm, math.radians(target_deg)),
                                     out=out, plot_dir=plot, quaternion_order=quaternion_order,
                                     position_units=position_units, no_reading=no_reading, warn=warn, progress=progress,
                                     report_html=report_html, command=invocation(ctx))
        for w in calibration_warnings(report):
            warn(w)
        if json_out:
            echo_json(report.to_dict(), "calibration")
        else:
            echo(calibration_text(report))

    @app.command("validate")
    @guarded
    def validate_cmd(
        ctx: typer.Context,
        export: Path = typer.Argument(..., help="Tracker export CSV of the validation poses" + STDIN),
        plane: Path = typer.Option(..., "--plane", help="Datum: fit-plane JSON, or a tracker cloud of the datum" + STDIN),
        layout: Path = typer.Option(..., "--layout", help="Layout TOML to validate (usually the calibrated one)" + STDIN),
        layout_before: Optional[Path] = typer.Option(None, "--layout-before", help="Layout to compare with (nominal)" + STDIN),
        json_out: bool = typer.Option(False, "--json", help=JSON_HELP + " Max, mean and std per layout, deg."),
        plot: Optional[Path] = typer.Option(None, "--plot", help="Write the deviation per pose here (.png/.pdf/.svg)."),
        tolerance_deg: float = typer.Option(0.5, "--tolerance-deg", help="Drilling tolerance on the normal, deg: "
                                            "the verdict, and the line on the plot."),
        report_html: Optional[Path] = typer.Option(None, "--report", help=REPORT_HELP),
        quaternion_order: str = typer.Option("wxyz", "--quaternion-order", help=QUATERNION_HELP),
        position_units: str = typer.Option("mm", "--position-units", help=POSITION_HELP),
        no_reading: Optional[float] = typer.Option(None, "--no-reading", help=NO_READING_HELP),
    ) -> None:
        """Angular deviation of the measured normal from the datum normal, per pose and layout."""
        _check_out_dir(plot, "--plot")
        from metrology.jobs.calibrate import validate_files
        from metrology.report.validation import validation_text

        if not tolerance_deg > 0:
            fail(f"--tolerance-deg must be positive, got {tolerance_deg:g}")

        with stdin_files(("EXPORT", export, ".csv"), ("--plane", plane, plane_suffix), ("--layout", layout, ".toml"),
                         ("--layout-before", layout_before, ".toml")) as (export, plane, layout, layout_before):
            report = validate_files(export, plane, layout, layout_before, plot=plot, quaternion_order=quaternion_order,
                                    position_units=position_units, no_reading=no_reading, warn=warn,
                                    tolerance_deg=tolerance_deg, report_html=report_html, command=invocation(ctx))
        if json_out:
            echo_json(report.to_dict(), "validation")
        else:
            echo(validation_text(report, tolerance_deg))
