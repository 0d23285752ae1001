"""``metro simulate-log``: a production cell's hole log, drawn by the independent forward simulator."""

from __future__ import annotations

from pathlib import Path
from typing import List, Optional

import typer

from ._common import JSON_HELP, echo, echo_json, fail, guarded, progress_bar, with_verdict


def register(app: typer.Typer) -> None:
    @app.command("simulate-log")
    @guarded
    def simulate_log(
        out: Path = typer.Option(..., "--out", help="The log: a .csv or .parquet file, or a new folder for "
                                 "partitioned Parquet (cell=C1/date=YYYY-MM-DD/, a hive dataset)."),
        layout: Optional[Path] = typer.Option(None, "--layout", help="The cell's calibrated layout TOML (default: "
                                              "the bundled Table 6 head, measured/nominal.toml)."),
        true_layout: Optional[Path] = typer.Option(None, "--true-layout", help="The head as it is (TOML); default: "
                                                   "one drawn from --layout's covariance (or moved by --layout-error-mm, -deg), from the seed."),
        truth: Optional[Path] = typer.Option(None, "--truth", help="Truth per hole_id (.csv or .parquet); default "
                                             "LOG.truth.csv (.parquet) beside a file, FOLDER.truth.parquet beside a "
                                             "folder."),
        no_truth: bool = typer.Option(False, "--no-truth", help="Write no truth file (a throughput run)."),
        holes: int = typer.Option(10_000, "--holes", help="Holes in all, split evenly over the cells."),
        cells: int = typer.Option(1, "--cells", help="Cells C1..CK (the same head), each its own time line."),
        panel: str = typer.Option("flat", "--panel", help="flat, sphere or cylinder (convex toward the head); a "
                                  "generated panel wing, barrel (concave, drilled from inside), nacelle, saddle; or a "
                                  "panel FILE (.stl, .obj, .ply, .glb; .step with the step extra), mm."),
        radius_mm: Optional[float] = typer.Option(None, "--radius-mm", help="Radius of a sphere or cylinder, mm."),
        azimuth_deg: Optional[float] = typer.Option(None, "--azimuth-deg", help="A cylinder's axis, deg from the "
                                                    "panel's x in its xy plane (default: along y, 90)."),
        points: Optional[Path] = typer.Option(None, "--points", help="Hole table hole_id,x,y,z,i,j,k (.csv or "
                                              ".parquet; mm, panel frame; i,j,k the feed into the panel): the holes "
                                              "are drilled at its points, in order, cycled; the log's hole_id is "
                                              "the table's (pass k >= 2: ID#k)."),
        controller: str = typer.Option("microplane", "--controller", help="The cell's attitude controller: "
                                       "microplane (plane through the spots) or metro (metro's corrected normal, "
                                       "with the CAD's curvature)."),
        off_cad: Optional[str] = typer.Option(None, "--off-cad", help="The true panel off its CAD (with --points): "
                                              "dent[:MM[@X,Y]] (0.2 mm over 100 mm), springback[:MM[@X]] (0.2 mm "
                                              "over 100 mm), shift[:X,Y,Z] (default 0,0,1 mm)."),
        noise_mm: Optional[float] = typer.Option(None, "--noise-mm", help="Reading noise, 1 sigma, mm (default: "
                                                 "the layout's noise_mm)."),
        angle_deg: str = typer.Option("0.5,5", "--angle-deg", help="MIN,MAX of the true angle between tool axis and "
                                      "surface normal before the adjustment (uniform), deg."),
        standoff_mm: Optional[float] = typer.Option(None, "--standoff-mm", help="Mean reading on a flat surface "
                                                    "square to the axis, mm (default: middle of range_mm)."),
        spin_deg: float = typer.Option(0.0, "--spin-deg", help="Turn of the head about the tool axis, uniform in "
                                       "[-SPIN, SPIN], deg."),
        patch_mm: float = typer.Option(400.0, "--patch-mm", help="Side of the square the drilling points cover, mm."),
        holes_per_hour: float = typer.Option(600.0, "--holes-per-hour", help="Each cell's drilling rate."),
        drift: Optional[List[str]] = typer.Option(None, "--drift", help="[CELL/]SENSOR:MM_PER_HOUR, then "
                                                  "@HOLE or none (L2:0.002@5000): a slow zero drift from hole HOLE (counted from 1; "
                                                  "none: from the first); repeatable."),
        shift: Optional[List[str]] = typer.Option(None, "--shift", help="[CELL/]SENSOR:MM@HOLE: a knocked sensor, "
                                                  "its zero jumps by MM at hole HOLE; repeatable."),
        gross_rate: float = typer.Option(0.0, "--gross-rate", help="Probability that a reading is gross "
                                         "(0.2-2 mm off)."),
        layout_error_mm: Optional[float] = typer.Option(None, "--layout-error-mm", help="Without --true-layout: "
                                                        "zero points moved by 0.5-1 times this, mm (default: a head "
                                                        "drawn from the layout's covariance; 0.03 without one)."),
        layout_error_deg: Optional[float] = typer.Option(None, "--layout-error-deg", help="Without --true-layout: "
                                                         "beams turned by 0.5-1 times this, deg (default: as "
                                                         "--layout-error-mm)."),
        seed: int = typer.Option(0, "--seed", help="Seed: same seed, same bytes."),
        json_out: bool = typer.Option(False, "--json", help=JSON_HELP + " What was written and how it was drawn."),
    ) -> None:
        """Write a realistic production hole log (readings before and after the attitude adjustment) with its truth."""
        from metrology.io.data import data_path
        from metrology.jobs.simulate_log import parse_drift, parse_range, parse_shift, simulate_log_files
        from metrology.report.simulate_log import simulate_log_text

        angles = parse_range(angle_deg, "--angle-deg", 0.0)
        drifts = [parse_drift(v) for v in drift or []]
        shifts = [parse_shift(v) for v in shift or []]
        layout = data_path("measured", "nominal.toml") if layout is None else layout
        for label, value in (("--layout", layout), ("--true-layout", true_layout), ("--points", points),
                             ("--panel", panel if Path(str(panel)).suffix else None)):
            if value is not None and not Path(value).exists():  # one wording for every input (docs/cli.md)
                fail(f"{value}: no such file ({label})")
            if value is not None and Path(value).is_dir():
                fail(f"{value}: a folder, not a file ({label})")
        with progress_bar("simulate-log") as progress:
            summary = simulate_log_files(
                layout, out, truth=truth, true_layout_path=true_layout, holes=holes, cells=cells, panel=panel,
                radius_mm=radius_mm, noise_mm=noise_mm, angle_deg=angles, standoff_mm=standoff_mm, spin_deg=spin_deg,
                patch_mm=patch_mm, holes_per_hour=holes_per_hour, drifts=drifts, shifts=shifts, gross_rate=gross_rate,
                layout_error_mm=layout_error_mm, layout_error_deg=layout_error_deg, seed=seed,
                write_truth=not no_truth, progress=progress, points=points, controller=controller,
                azimuth_deg=azimuth_deg, off_cad=off_cad)
        if json_out:
            from metrology.report.verdicts import NO_VERDICT

            echo_json(with_verdict(summary, NO_VERDICT), "simulate-log")  # it judges nothing
        else:
            from metrology.report.verdicts import NO_VERDICT_LINE

            echo(simulate_log_text(summary) + "\n" + NO_VERDICT_LINE)
