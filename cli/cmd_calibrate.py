"""``metro calibrate`` and ``metro validate``: sensor calibration from measured files."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from ._common import (JSON_HELP, NO_READING_HELP, POSITION_HELP, QUATERNION_HELP, REPORT_HELP, echo, echo_json, fail,
                      finish, guarded, invocation, progress_bar, reported, warn, with_verdict)
from ._stdin import STDIN_NAME, plane_suffix, stdin_files

STDIN = " ('-' for stdin)"

METHODS = ("lsq", "iekf", "ekf", "ekf_paper", "method1")


def _check_out_dir(path: Optional[Path], what: str) -> None:
    """Fail before any work when an output's directory does not exist (nothing written)."""
    if path is not None and not Path(path).resolve().parent.is_dir():
        fail(f"{what} {path}: directory {Path(path).parent} does not exist")


META_KEY = r"[A-Za-z][A-Za-z0-9_-]*"


def _meta(pairs, meta_file) -> dict:
    """The certificate's header fields: ``--meta-file`` (a TOML table of key = value), then each
    ``--meta key=value`` (later wins); one-line errors naming the option."""
    import re
    import tomllib

    meta = {}
    if meta_file is not None:
        try:
            with open(meta_file, "rb") as fh:
                data = tomllib.load(fh)
        except FileNotFoundError:
            fail(f"{meta_file}: no such file (--meta-file)")
        except OSError as exc:
            fail(f"--meta-file {meta_file}: cannot read ({exc.strerror})")
        except tomllib.TOMLDecodeError as exc:
            fail(f"--meta-file {meta_file}: not valid TOML ({exc})")
        data = data.get("certificate", data) if isinstance(data.get("certificate"), dict) else data
        for k, v in data.items():
            if isinstance(v, (dict, list)):
                fail(f"--meta-file {meta_file}: '{k}' must be a value (text, number or date), not a table or array")
            meta[str(k)] = str(v)
    for pair in pairs or ():
        key, eq, value = pair.partition("=")
        if not eq or not re.fullmatch(META_KEY, key.strip()):
            fail(f"--meta {pair!r}: expected key=value (the key letters, digits, _ or -), e.g. --meta operator=J.Smith")
        meta[key.strip()] = value.strip()
    return meta


def _follow(export, plane, layout, method, out, json_out, target_mm, target_deg, target_normal_deg, idle_s,
            stop_when_met, quaternion_order, position_units, no_reading, target_set=False) -> None:
    """``calibrate --follow``: one line per pose (stderr with --json), then the final report."""
    import math

    if method not in ("lsq", "iekf"):
        fail(f"--follow runs the iterated EKF; --method {method} cannot follow")
    if not idle_s >= 0:
        fail(f"--idle-s {idle_s:g}: expected a number >= 0")
    if target_normal_deg is not None and not target_normal_deg > 0:
        fail(f"--target-normal-deg {target_normal_deg:g}: expected a positive number")
    from metrology.calibration.follow import Targets
    from metrology.io.layout import save_layout
    from metrology.jobs.follow import follow_export
    from metrology.report.calibration import calibration_text, calibration_warnings
    from metrology.report.plan import follow_line

    targets = Targets(target_mm, math.radians(target_deg),
                      None if target_normal_deg is None else math.radians(target_normal_deg))
    said = []

    def on_step(step):
        typer.echo(follow_line(step), err=json_out)
        if step.met and not said:
            said.append(step.k)
            typer.echo(f"targets met after {step.k} poses (pose {step.pose_id}): the robot can stop", err=json_out)

    name = STDIN_NAME if str(export) == "-" else str(export)
    result = follow_export(str(export), plane, layout, targets, on_step, idle_s=idle_s, stop_when_met=stop_when_met,
                           quaternion_order=quaternion_order, position_units=position_units, no_reading=no_reading,
                           name=name, target_set=target_set)
    if out is not None:
        save_layout(result.report.layout, out, f"Calibrated by metro calibrate --follow (iterated EKF), {name}, "
                    f"{len(result.steps)} poses")
    for w in calibration_warnings(result.report):
        warn(w)
    if json_out:
        echo_json(result.to_dict(), "follow")
    else:
        typer.echo(f"stopped: {result.stopped} after {len(result.steps)} poses; final: batch iterated EKF on them")
        typer.echo(calibration_text(result.report))
    finish(result.report.verdict())


def register(app: typer.Typer) -> None:
    @app.command("calibrate")
    @guarded
    def calibrate_cmd(
        ctx: typer.Context,
        export: Path = typer.Argument(..., help="Tracker export CSV (pose_id,x,y,z,qw,qx,qy,qz,d_<sensor>,...)" + STDIN
                             + "; with --follow, a file that grows or stdin"),
        plane: Path = typer.Option(..., "--plane", help="Datum: fit-plane JSON, or a tracker cloud of the datum" + STDIN),
        layout: Path = typer.Option(..., "--layout", help="Nominal sensor layout TOML" + STDIN),
        method: str = typer.Option("lsq", "--method", help=f"Estimator: {', '.join(METHODS)}."),
        json_out: bool = typer.Option(False, "--json", help=JSON_HELP),
        out: Optional[Path] = typer.Option(None, "--out", help="Write the calibrated layout TOML here."),
        qif: Optional[Path] = typer.Option(None, "--qif", help="Also write the calibrated head as a QIF 3.0 "
                                           "measurement device (.qif): its sensors' calibrated values and the "
                                           "SHA-256 of the calibrated layout, which metro measure --qif names."),
        dfq: Optional[Path] = typer.Option(None, "--dfq", help="Also write the calibrated parameters as a Q-DAS "
                                           "AQDEF file (.dfq) for SPC: per sensor its zero point (mm) and beam "
                                           "direction, nominal the layout's; the calibration's SHA-256 as gauge."),
        plot: Optional[Path] = typer.Option(None, "--plot", help="Convergence and residual figures: a .pdf file (a "
                                            "page each) or a directory (PNGs)."),
        report_html: Optional[Path] = typer.Option(None, "--report", help=REPORT_HELP),
        target_mm: Optional[float] = typer.Option(None, "--target-mm", help="Precision target: wanted 1 σ of the "
                                                  "zero points, mm; not met: exit 1. Default: 0.05, information only."),
        target_deg: Optional[float] = typer.Option(None, "--target-deg", help="Precision target: wanted 1 σ of the "
                                                   "beam tilts, deg; not met: exit 1. Default: 0.05, information only."),
        target_zero_mm: Optional[float] = typer.Option(None, "--target-zero-mm", hidden=True),  # old name of --target-mm
        target_beam_deg: Optional[float] = typer.Option(None, "--target-beam-deg", hidden=True),  # of --target-deg
        target_normal_deg: Optional[float] = typer.Option(None, "--target-normal-deg", help="--follow: wanted 1-sigma of the normal at the working stand-off, deg."),
        follow: bool = typer.Option(False, "--follow", help="Read poses as they are appended (EXPORT may be '-' for stdin); iterated EKF pose by pose."),
        idle_s: float = typer.Option(5.0, "--idle-s", help="--follow: stop after this many seconds with no new line."),
        stop_when_met: bool = typer.Option(False, "--stop-when-met", help="--follow: stop reading when every target is met."),
        quaternion_order: str = typer.Option("wxyz", "--quaternion-order", help=QUATERNION_HELP),
        position_units: str = typer.Option("mm", "--position-units", help=POSITION_HELP),
        no_reading: Optional[float] = typer.Option(None, "--no-reading", help=NO_READING_HELP),
        meta: Optional[list[str]] = typer.Option(None, "--meta", help="A certificate header field, key=value "
                                                 "(repeat): part, instrument, serial, operator, temperature, notes, "
                                                 "customer, certificate, approved_by, valid_until ...; also written "
                                                 "into --out's [certificate] table."),
        meta_file: Optional[Path] = typer.Option(None, "--meta-file", help="The certificate header fields as a TOML "
                                                 "table of key = value (--meta given too wins)."),
    ) -> None:
        """Calibrate the normal sensors from a tracker export, the datum and the nominal layout."""
        if method not in METHODS:
            fail(f"--method {method!r}: expected one of {', '.join(METHODS)}")
        from metrology.core.tolerances import TARGET_TILT_DEG, TARGET_ZERO_MM

        target_mm = target_zero_mm if target_mm is None else target_mm
        target_deg = target_beam_deg if target_deg is None else target_deg
        target_set = target_mm is not None or target_deg is not None
        target_mm = TARGET_ZERO_MM if target_mm is None else target_mm
        target_deg = TARGET_TILT_DEG if target_deg is None else target_deg
        if not (target_mm > 0 and target_deg > 0):
            fail(f"--target-mm and --target-deg must be positive, got {target_mm:g} and {target_deg:g}")
        _check_out_dir(out, "--out")
        fields = _meta(meta, meta_file)
        import math

        if follow:
            if plot is not None or report_html is not None or qif is not None or dfq is not None:
                fail("--follow writes no figures, report or QIF: run calibrate on the finished file for --plot/--report/"
                     "--qif/--dfq")
            return _follow(export, plane, layout, method, out, json_out, target_mm, target_deg, target_normal_deg,
                           idle_s, stop_when_met, quaternion_order, position_units, no_reading, target_set)

        from metrology.jobs.calibrate import calibrate_files
        from metrology.report.calibration import calibration_text, calibration_warnings

        with stdin_files(("EXPORT", export, ".csv"), ("--plane", plane, plane_suffix),
                         ("--layout", layout, ".toml")) as (export, plane, layout), progress_bar("calibrate") as progress:
            report = calibrate_files(export, plane, layout, method, target=(target_mm, math.radians(target_deg)),
                                     target_set=target_set,
                                     out=out, plot_dir=plot, quaternion_order=quaternion_order,
                                     position_units=position_units, no_reading=no_reading, warn=warn, progress=progress,
                                     report_html=report_html, command=invocation(ctx), meta=fields, qif=qif,
                                     dfq=dfq)
        for w in calibration_warnings(report):
            warn(w)
        if json_out:
            echo_json(report.to_dict(), "calibration")
        else:
            echo(calibration_text(report))
        reported(report_html)
        finish(report.verdict())

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
        per_pose: Optional[Path] = typer.Option(None, "--per-pose", help="Write each pose's deviation per layout and "
                                                "whether it is within the tolerance (.csv)."),
    ) -> None:
        """Angular deviation of the measured normal from the datum normal, per pose and layout."""
        _check_out_dir(plot, "--plot")
        from metrology.jobs.calibrate import validate_files
        from metrology.report.validation import validation_text, validation_verdict
        from metrology.report.verdicts import validation_checks

        if not tolerance_deg > 0:
            fail(f"--tolerance-deg must be positive, got {tolerance_deg:g}")

        with stdin_files(("EXPORT", export, ".csv"), ("--plane", plane, plane_suffix), ("--layout", layout, ".toml"),
                         ("--layout-before", layout_before, ".toml")) as (export, plane, layout, layout_before):
            report = validate_files(export, plane, layout, layout_before, plot=plot, quaternion_order=quaternion_order,
                                    position_units=position_units, no_reading=no_reading, warn=warn,
                                    tolerance_deg=tolerance_deg, report_html=report_html, command=invocation(ctx),
                                    per_pose=per_pose)
        verdict = validation_checks(validation_verdict(report, tolerance_deg))
        if json_out:
            echo_json(with_verdict({**report.to_dict(), "tolerance_deg": tolerance_deg}, verdict), "validation")
        else:
            echo(validation_text(report, tolerance_deg))
        reported(report_html)
        finish(verdict)
