"""``metro diagnose`` (what the simple model misses, named and measured) and ``metro simulate``
(exports hiding a catalogued effect)."""

from __future__ import annotations

from pathlib import Path

import typer

from ._common import (JSON_HELP, NO_READING_HELP, POSITION_HELP, QUATERNION_HELP, dumps, echo, echo_json, fail, finish,
                      guarded, invocation, progress_bar, reported, warn, with_verdict)
from ._stdin import plane_suffix, stdin_files

STDIN = " ('-' for stdin)"


def register(app: typer.Typer) -> None:
    @app.command("diagnose")
    @guarded
    def diagnose(
        ctx: typer.Context,
        export: Path = typer.Argument(..., help="tracker export CSV" + STDIN),
        plane: Path = typer.Option(..., "--plane", help="datum plane JSON or datum cloud" + STDIN),
        layout: Path = typer.Option(..., "--layout", help="sensor layout TOML (with noise_mm)" + STDIN),
        json_out: bool = typer.Option(False, "--json", help=JSON_HELP),
        report: Path = typer.Option(None, "--report", help="an .html file: one self-contained report; any other "
                                    "path: a directory for the residual plots (PNG)"),
        folds: int = typer.Option(5, "--folds", help="k of the k-fold-by-pose held-out figures"),
        seed: int = typer.Option(0, "--seed", help="seed of the side-by-side simulation's noise"),
        quaternion_order: str = typer.Option("wxyz", "--quaternion-order", help=QUATERNION_HELP),
        position_units: str = typer.Option("mm", "--position-units", help=POSITION_HELP),
        no_reading: float = typer.Option(None, "--no-reading", help=NO_READING_HELP),
        explain: bool = typer.Option(False, "--explain", help="Print the verdict and the rules that made it, in the "
                                     "order they fired (rule number and name, statistic, level, candidates), instead "
                                     "of the full report (the --json output carries them as 'reasons')."),
        fail_on_cause: bool = typer.Option(False, "--fail-on-cause", help="Exit 1 when a cause is named (or the "
                                           "residuals stay unexplained), not only when the normal is out of tolerance."),
        out: Path = typer.Option(None, "--out", help="Write the layout refitted with the head terms named (gain, "
                                 "incidence, characteristic, temperature coefficient) and their joint covariance: "
                                 "metro calibrate and metro measure apply it (docs/diagnose.md)."),
    ) -> None:
        """Find what the base model misses, name it from the catalogue, extend, measure the gain."""
        from metrology.jobs.diagnose import check_report_target, diagnose_files, diagnose_report, extend_files
        from metrology.report.diagnose import explain_text, report_text
        from metrology.report.verdicts import diagnosis_verdict, verdict_text

        if folds < 2:
            fail(f"--folds must be at least 2, got {folds}")
        if report is not None:
            check_report_target(report)
        with stdin_files(("EXPORT", export, ".csv"), ("--plane", plane, plane_suffix),
                         ("--layout", layout, ".toml")) as (export_p, plane_p, layout_p), progress_bar("diagnose") as progress:
            ext = None
            if out is None:
                d = diagnose_files(export_p, plane_p, layout_p, quaternion_order, position_units, no_reading,
                                   warn=warn, folds=folds, seed=seed, progress=progress)
            else:
                d, ext = extend_files(export_p, plane_p, layout_p, out, quaternion_order, position_units, no_reading,
                                      warn=warn, folds=folds, seed=seed, progress=progress)
            verdict = diagnosis_verdict(d, fail_on_cause=fail_on_cause)
            data = d.to_dict() | ({} if ext is None else {"layout_out": {"path": str(out), **ext.to_dict()}})
            text = dumps(with_verdict(data, verdict), "diagnosis") if json_out else \
                (explain_text(d) if explain else report_text(d)) + "\n" + verdict_text(verdict) \
                + ("" if ext is None else f"\n{ext.words()}\nwritten: {out}")
            html = report is not None and str(report).lower().endswith((".html", ".htm"))
            if report is not None:  # inside: a report reads the inputs' checksums
                progress(0, 1, "writing the report")
                sources = {"export": str(export_p), "plane": str(plane_p), "layout": str(layout_p)}
                files = diagnose_report(d, report, sources, command=invocation(ctx), seed=seed)
                if not json_out and not html:
                    text += "\n\nplots: " + ", ".join(files)
        echo(text)
        if html:
            reported(report)
        finish(verdict)

    @app.command("simulate")
    @guarded
    def simulate(
        layout: Path = typer.Option(..., "--layout", help="true sensor layout TOML (noise_mm required)" + STDIN),
        plane: Path = typer.Option(..., "--plane", help="datum plane JSON (tracker frame)" + STDIN),
        out: Path = typer.Option(..., "--out", help="export CSV to write"),
        effect: str = typer.Option(None, "--effect", help="effect to hide (catalogue name, or 'periodic')"),
        sensor: str = typer.Option(None, "--sensor", help="sensor it acts on (not for plane_form, pose_error)"),
        size: float = typer.Option(None, "--size", help="effect size (see docs: its unit depends on the effect)"),
        poses: int = typer.Option(80, "--poses", help="number of poses"),
        seed: int = typer.Option(0, "--seed", help="random seed"),
        json_out: bool = typer.Option(False, "--json", help=JSON_HELP + " What was hidden."),
        cloud: Path = typer.Option(None, "--cloud", help="also write a tracker scan of the datum (PLY), with the "
                                   "plane_form effect if hidden"),
    ) -> None:
        """Write a synthetic export hiding an effect of chosen size on a chosen sensor."""
        from metrology.jobs.simulate import simulate_files
        from metrology.report.diagnose import simulate_text
        from metrology.report.verdicts import NO_VERDICT

        with stdin_files(("--layout", layout, ".toml"), ("--plane", plane, ".json")) as (layout, plane):
            truth, n_points = simulate_files(layout, plane, out, effect, sensor, size, poses, seed, cloud)
        if json_out:
            echo_json(with_verdict(truth, NO_VERDICT), "simulation")
        else:
            from metrology.report.verdicts import NO_VERDICT_LINE

            echo(simulate_text(out, poses, effect, sensor, size, cloud, n_points) + "\n" + NO_VERDICT_LINE)
