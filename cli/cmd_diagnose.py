"""``metro diagnose`` (what the simple model misses, named and measured) and ``metro simulate``
(exports hiding a catalogued effect)."""

from __future__ import annotations

from pathlib import Path

import typer

from ._common import dumps, echo_json, fail, guarded


def _p(p: float) -> str:
    """``= 0.0123`` or ``< 1e-300`` (a p-value that underflowed)."""
    return "< 1e-300" if p < 1e-300 else f"= {p:.3g}"


def _report_text(d) -> str:
    D = d.to_dict()
    lines = [f"cause: {D['cause']}" + (f" ({', '.join(D['sensors'])})" if D["sensors"] else "")
             + f"   confidence: {D['confidence']}", f"  {D['summary']}", ""]
    disc = D["discrepancy"]
    lines.append("discrepancy (residual RMS um per sensor; held-out normal deviation deg)")
    head = f"  {'':28s}" + "".join(f"{n:>9s}" for n in disc["sensors"]) + f"{'normal':>11s}"
    lines.append(head)

    def row(label, rms, nd):
        return f"  {label:28s}" + "".join(f"{1e3 * v:9.2f}" for v in rms) + ("" if nd is None else f"{nd:11.5f}")

    lines.append(row("stated noise", disc["stated_noise_mm"], None))
    lines.append(row("simulation, base model", disc["simulated_base_residual_rms_mm"],
                     disc["simulated_base_heldout_normal_deg"]))
    lines.append(row("measured", disc["measured_residual_rms_mm"], disc["measured_heldout_normal_deg"]))
    if "simulated_extended_residual_rms_mm" in disc:
        lines.append(row(f"simulation, + {disc['extended_model']}", disc["simulated_extended_residual_rms_mm"],
                         disc["simulated_extended_heldout_normal_deg"]))
    lines.append("")
    tb = D["tests"]["base"]
    lines.append(f"noise-model tests on the base residuals (Bonferroni p = {tb['p_bonferroni']:.3g}, "
                 f"{tb['n_tests']} tests): " + ("consistent" if tb["consistent"] else "INCONSISTENT"))
    for n, t in tb["sensors"].items():
        lines.append(f"  {n}: sigma {1e3 * t['sigma_est_mm']:.2f} um  p_chi2 {t['p_chi2']:.3g}  "
                     f"p_white {t['p_whiteness']:.3g}  p_normal {t['p_normality']:.3g}")
    lines.append("")
    lines.append("candidates (held-out k-fold by pose), best first")
    lines.append(f"  {'candidate':22s}{'p in-sample':>12s}{'p held-out':>12s}{'chi2 gain':>11s}{'RMS ratio':>11s}  sig")
    for c in D["candidates"][:10]:
        lines.append(f"  {c['label']:22s}{c['p_insample']:12.3g}{c['p_heldout']:12.3g}"
                     f"{c['heldout_chi2_reduction']:11.1f}{c['heldout_rms_ratio']:11.3f}  {'*' if c['significant'] else ''}")
    if len(D["candidates"]) > 10:
        lines.append(f"  ... {len(D['candidates']) - 10} more in --json")
    if D["extended"]:
        lines.append("")
        lines.append(f"extended model: {D['extended']['label']}")
        for k, v in D["extended"]["params"].items():
            se = "" if v["stderr"] is None else f" +- {v['stderr']:.3g}"
            lines.append(f"  {k} = {v['value']:.4g}{se} {v['unit']}")
        h = D["heldout"]
        lines.append(f"held-out ({h['folds']}-fold): RMS {1e3 * h['base_rms_mm']:.3f} -> {1e3 * h['extended_rms_mm']:.3f} um "
                     f"(ratio {h['rms_ratio']:.3f}; its sensors {h['rms_ratio_concerned']:.3f}), normal "
                     f"{h['base_normal_deg']:.5f} -> {h['extended_normal_deg']:.5f} deg (ratio {h['normal_ratio']:.3f})")
    for c in D["confounding"]:
        lines.append(f"confounding: {c['message']}")
    df = D["datum_form"]
    if df is not None:
        q = "  ".join(f"{k[:-3]} {v['value'] * 1e3:.2f} +- {v['stderr'] * 1e3:.2f}" for k, v in df["params"].items()
                      if k in ("b_ss_mm", "b_st_mm", "b_tt_mm"))
        vis = ", ".join(f"{1e3 * v:.2f}" for v in df["visible_rms_mm"])
        ag = df["against_readings"]
        lines += ["", f"datum cloud ({df['points_used']} of {df['points']} points, {df['window']}): form {q} um at "
                      f"{df['radius_mm']:g} mm (quadratic p {_p(df['p_quadratic'])})",
                  f"  at this run's spots it would leave {vis} um RMS in the base residuals (per sensor)",
                  f"  the readings' plane_form ({' + '.join(ag['fitted_with'])}) {'agrees' if ag['agree'] else 'DISAGREES'} "
                  f"with it (p {_p(ag['p'])})"]
    return "\n".join(lines)


def register(app: typer.Typer) -> None:
    @app.command("diagnose")
    @guarded
    def diagnose(
        export: Path = typer.Argument(..., help="tracker export CSV"),
        plane: Path = typer.Option(..., "--plane", help="datum plane JSON or datum cloud"),
        layout: Path = typer.Option(..., "--layout", help="sensor layout TOML (with noise_mm)"),
        json_out: bool = typer.Option(False, "--json", help="print the full result as JSON"),
        report: Path = typer.Option(None, "--report", help="directory for the residual plots"),
        folds: int = typer.Option(5, "--folds", help="k of the k-fold-by-pose held-out figures"),
        seed: int = typer.Option(0, "--seed", help="seed of the side-by-side simulation's noise"),
    ) -> None:
        """Find what the base model misses, name it from the catalogue, extend, measure the gain."""
        from metrology.jobs.diagnose import diagnose_files
        from metrology.report.diagnose import plot_report

        if folds < 2:
            fail(f"--folds must be at least 2, got {folds}")
        d = diagnose_files(export, plane, layout, folds=folds, seed=seed)
        text = dumps(d.to_dict()) if json_out else _report_text(d)
        if report is not None:
            files = plot_report(d, report)
            if not json_out:
                text += "\n\nplots: " + ", ".join(files)
        typer.echo(text)

    @app.command("simulate")
    @guarded
    def simulate(
        layout: Path = typer.Option(..., "--layout", help="true sensor layout TOML (noise_mm required)"),
        plane: Path = typer.Option(..., "--plane", help="datum plane JSON (tracker frame)"),
        out: Path = typer.Option(..., "--out", help="export CSV to write"),
        effect: str = typer.Option(None, "--effect", help="effect to hide (catalogue name, or 'periodic')"),
        sensor: str = typer.Option(None, "--sensor", help="sensor it acts on (not for plane_form, pose_error)"),
        size: float = typer.Option(None, "--size", help="effect size (see docs: its unit depends on the effect)"),
        poses: int = typer.Option(80, "--poses", help="number of poses"),
        seed: int = typer.Option(0, "--seed", help="random seed"),
        json_out: bool = typer.Option(False, "--json", help="print what was hidden as JSON"),
        cloud: Path = typer.Option(None, "--cloud", help="also write a tracker scan of the datum (PLY), with the "
                                   "plane_form effect if hidden"),
    ) -> None:
        """Write a synthetic export hiding an effect of chosen size on a chosen sensor."""
        import numpy as np

        from metrology.io.atomic import atomic_path
        from metrology.io.clouds import write_ply
        from metrology.io.export import write_export
        from metrology.io.layout import load_layout
        from metrology.core.plane import Plane
        from metrology.sim.synth import HiddenEffect, synth_cloud, synth_run

        if (effect is None) != (size is None):
            fail("--effect and --size go together")
        lay = load_layout(layout)
        pl = Plane.from_json(plane)
        effects = [] if effect is None else [HiddenEffect(effect, sensor, size)]
        if effect is None and sensor is not None:
            fail("--sensor needs --effect")
        if cloud is not None and cloud.suffix.lower() != ".ply":
            fail(f"--cloud {cloud}: expected a .ply path")
        if cloud is not None and not cloud.parent.is_dir():
            fail(f"--cloud {cloud}: directory {cloud.parent} does not exist")
        rng = np.random.default_rng(seed)
        export, truth = synth_run(rng, lay, pl, poses, effects)
        points = None if cloud is None else synth_cloud(rng, pl, effects)
        if points is None:
            write_export(export, out)
        else:  # both files or neither: each is written to a temporary beside it, moved at the end
            with atomic_path(out) as tmp_out, atomic_path(cloud) as tmp_cloud:
                write_export(export, tmp_out)
                write_ply(tmp_cloud, points, [f"metro simulate: tracker scan of the datum, mm, tracker frame (seed {seed})"])
        if json_out:
            echo_json(truth)
        else:
            typer.echo(f"wrote {out}: {poses} poses" + (f", hiding {effect} of size {size:g}"
                                                       + (f" on {sensor}" if sensor else "") if effect else "")
                       + (f"; {cloud}: {len(points)} datum points" if points is not None else ""))
