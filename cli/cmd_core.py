"""Core commands: ``reproduce`` (paper section 5) and ``demo`` (the bundled walk-through)."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Optional

import typer

from ._common import dumps, fail, guarded


def _table(rows, header):
    widths = [max(len(str(r[i])) for r in rows + [header]) for i in range(len(header))]
    line = "  ".join(h.ljust(w) if i == 0 else h.rjust(w) for i, (h, w) in enumerate(zip(header, widths)))
    out = [line, "-" * len(line)]
    for r in rows:
        out.append("  ".join(str(c).ljust(w) if i == 0 else str(c).rjust(w) for i, (c, w) in enumerate(zip(r, widths))))
    return "\n".join(out)


def format_reproduce(s: dict) -> str:
    """The readable report of :func:`metrology.reproduce.summarise`."""
    cfg = s["config"]
    lines = [
        f"metro reproduce: layout {s['layout']}, {s['trials']} trial(s), seed {s['seed']}",
        f"  {cfg['n_poses']} calibration poses, reading noise {cfg['noise_mm']} mm; datum {cfg['n_datum_points']} points "
        f"at {cfg['datum_noise_mm']} mm over {cfg['datum_size_mm']:g} mm; stand-off {cfg['standoff_mm'][0]:g}-"
        f"{cfg['standoff_mm'][1]:g} mm, tilt <= {cfg['tilt_max_deg']:g} deg, spread {cfg['spread_mm']:g} mm; "
        f"{cfg['n_workpiece']} workpiece poses; paper EKF Q={cfg['ekf_paper']['Q']:g} R={cfg['ekf_paper']['R']:g} "
        f"delta={cfg['ekf_paper']['delta']:g}",
        "",
        "Table 1 analogue: datum plane (A, B, C, D), trial 1",
    ]
    t1 = s["table1"]
    rows = [["theoretical"] + [f"{v:.4f}" for v in t1["theoretical"]], ["fitted (metro)"] + [f"{v:.4f}" for v in t1["fitted_trial1"]]]
    if t1["paper_fitted"]:
        rows.append(["fitted (paper)"] + [f"{v:.4f}" for v in t1["paper_fitted"]])
    lines += [_table(rows, ["", "A", "B", "C", "D"]), ""]
    t3 = s["table3"]
    lines.append("Table 3 analogue: measurements to the paper's stopping rule (-: never met)")
    fmt = lambda v: "-" if v is None or v < 0 else f"{v:g}"  # noqa: E731
    rows = [["trial 1"] + [fmt(v) for v in t3["n_converged_trial1"]],
            ["never met (share)"] + [f"{v:.0%}" for v in t3["never_converged_fraction"]],
            ["median if met"] + [fmt(v) for v in t3["median_when_converged"]],
            ["paper"] + [str(v) for v in t3["paper"]]]
    lines += [_table(rows, [""] + t3["sensors"]), ""]
    spread = s["trials"] > 1
    lines.append("Table 4 analogue: angular deviation of the measured normal on the workpiece [deg]"
                 + (" (mean +- spread over trials)" if spread else ""))
    rows = []
    for m, r in s["table4"].items():
        cell = lambda k: f"{r[k]:.4f}" + (f" +- {r[k.replace('_deg', '_spread_deg')]:.4f}" if spread else "")  # noqa: E731
        p = s["paper_table4"].get(m)
        rows.append([m, cell("max_deg"), cell("mean_deg"), cell("std_deg"), f"{r['zero_error_mm']:.3f}",
                     f"{r['direction_error_deg']:.3f}", "" if p is None else f"{p['max_deg']:.4f}/{p['mean_deg']:.4f}/{p['std_deg']:.4f}"])
    lines.append(_table(rows, ["method", "max", "mean", "std", "max|dE| mm", "max dir err deg", "paper max/mean/std"]))
    lines.append("  before = nominal layout; true = the true parameters (the floor set by reading noise).")
    return "\n".join(lines)


#: the demo's steps: (title, command line with {fx} = fixtures dir and {out} = output dir)
DEMO_STEPS = (
    ("1. Fit the datum plane from the tracker cloud",
     "fit-plane {fx}/measured/datum.ply --out {out}/plane.json --plot {out}/datum_residuals.png"),
    ("2. Calibrate the sensors (batch least squares, with uncertainties and identifiability)",
     "calibrate {fx}/measured/calibration.csv --plane {out}/plane.json --layout {fx}/measured/nominal.toml "
     "--out {out}/calibrated.toml --plot {out}/calibration"),
    ("3. Validate on held-out poses: nominal against calibrated layout",
     "validate {fx}/measured/validation.csv --plane {out}/plane.json --layout {out}/calibrated.toml "
     "--layout-before {fx}/measured/nominal.toml --plot {out}/validation.png"),
    ("4. Diagnose a measured data set that hides an effect the simple model lacks",
     "diagnose {fx}/hidden/export.csv --plane {fx}/hidden/plane.json --layout {fx}/hidden/layout.toml "
     "--report {out}/diagnose"),
    ("5. Micro-plane against micro-sphere normals on a curved panel (R = 800 mm)",
     "normals {fx}/panel_cyl800.stl --layout {fx}/layout_table6.toml --grid 40 --tilt-deg 2 --seed 1 "
     "--plot {out}/panel_errors.png"),
)


def register(app: typer.Typer) -> None:
    @app.command("demo")
    def demo(
        fixtures: Path = typer.Option(Path("fixtures"), help="The bundled fixtures directory (run from the repository root)."),
        out: Path = typer.Option(Path("metro-demo"), help="Directory for the demo's outputs."),
    ) -> None:
        """Run the main job on the bundled fixtures: fit-plane -> calibrate -> validate -> diagnose -> normals."""
        import shlex

        from typer.main import get_command

        if not (fixtures / "measured").is_dir():
            fail(f"{fixtures}: bundled fixtures not found (run from the repository root, or pass --fixtures DIR)")
        out.mkdir(parents=True, exist_ok=True)
        command = get_command(app)
        for title, line in DEMO_STEPS:
            args = shlex.split(line.format(fx=fixtures, out=out))
            typer.secho(f"\n== {title}\n$ metro {' '.join(args)}", bold=True)
            rc = command.main(args, prog_name="metro", standalone_mode=False)
            if rc:  # a failing step has printed its one-line error
                raise typer.Exit(rc)
        typer.echo(f"\ndemo outputs in {out}/")

    @app.command("version")
    def version() -> None:
        """Print metro's version."""
        from metrology import __version__

        typer.echo(__version__)

    @app.command("reproduce")
    @guarded
    def reproduce(
        layout: str = typer.Option("simulation", help="simulation (Tables 1-2) or experiment (Tables 5-6, its Q and R)."),
        trials: int = typer.Option(1, min=1, help="Repeat with N seeds; report mean and spread."),
        seed: int = typer.Option(2018, help="Seed of the first trial's random stream."),
        poses: int = typer.Option(100, min=6, help="Calibration poses."),
        noise_mm: float = typer.Option(0.01, min=0.0, help="Reading noise, 1 sigma [mm]."),
        tilt_deg: float = typer.Option(5.0, min=0.0, max=60.0, help="Largest tilt of the tool axis from the datum normal [deg]."),
        standoff_mm: tuple[float, float] = typer.Option((40.0, 60.0), help="Range of the mean reading (stand-off) [mm]."),
        spread_mm: float = typer.Option(200.0, min=0.0, help="Side of the square the drilling points spread over [mm]."),
        figures: Optional[Path] = typer.Option(Path("metro-reproduce"), help="Directory for Figures 7 and 8 (PNG); '-' for none."),
        json_out: bool = typer.Option(False, "--json", help="Machine-readable output on stdout."),
    ) -> None:
        """Reproduce the paper's simulation (section 5): Tables 1, 3, 4 and Figures 7, 8."""
        import numpy as np

        from metrology.sim.reproduce import ReproduceConfig, run_trials, summarise
        from metrology.sim.simulation import PoseSpec

        if standoff_mm[0] >= standoff_mm[1] or standoff_mm[0] <= 0:
            fail(f"--standoff-mm {standoff_mm[0]:g} {standoff_mm[1]:g}: expected 0 < min < max")
        fig_dir = None if figures is None or str(figures) == "-" else figures
        cfg = ReproduceConfig(layout=layout, n_poses=poses, noise_mm=noise_mm,
                              poses=PoseSpec(tuple(standoff_mm), float(np.deg2rad(tilt_deg)), spread_mm))
        if json_out or not sys.stderr.isatty():
            results = run_trials(cfg, seed, trials)
        else:
            with typer.progressbar(length=trials, label="trials", file=sys.stderr) as bar:
                results = run_trials(cfg, seed, trials, progress=lambda: bar.update(1))
        summary = summarise(cfg, results, seed)
        if fig_dir is not None:
            from metrology.report.plots import figure7, figure8

            fig_dir.mkdir(parents=True, exist_ok=True)
            nominal, true, _, _ = cfg.tables()
            true_err = np.concatenate([true.zero - nominal.zero, true.direction - nominal.direction], axis=1)
            figure7(results[0].ekf_history, true_err, nominal.names, fig_dir / "figure7_ekf_convergence.png")
            figure8(results[0].deviation_deg, fig_dir / "figure8_angular_deviation.png")
            summary["figures"] = [str(fig_dir / "figure7_ekf_convergence.png"), str(fig_dir / "figure8_angular_deviation.png")]
        if json_out:
            typer.echo(dumps(summary))
        else:
            typer.echo(format_reproduce(summary))
            if fig_dir is not None:
                typer.echo(f"figures: {', '.join(summary['figures'])}")
