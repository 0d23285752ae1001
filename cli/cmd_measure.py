"""``metro measure``: every hole of a cell's log measured, judged and watched for drift."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from ._common import JSON_HELP, REPORT_HELP, echo_json, fail, finish, guarded, invocation, progress_bar, reported, warn


def register(app: typer.Typer) -> None:
    @app.command("measure")
    @guarded
    def measure(
        ctx: typer.Context,
        log: str = typer.Argument(..., help="The hole log: .csv ('-' for stdin), .parquet, or a folder of hive-"
                                  "partitioned .parquet (cell=C1/date=YYYY-MM-DD/)."),
        layout: Path = typer.Option(..., "--layout", help="The calibrated layout (.toml) from metro calibrate --out; "
                                    "its [calibration] covariance is propagated into U95."),
        out: Optional[Path] = typer.Option(None, "--out", help="Per-hole results: .csv or .parquet, or a folder for a "
                                           "partitioned log (one file per partition; a re-run resumes). Default: CSV "
                                           "on stdout (with --json: none, the summary alone)."),
        tolerance_deg: float = typer.Option(0.5, "--tolerance-deg", help="Perpendicularity tolerance, deg: the "
                                            "largest angle between drill axis and surface normal."),
        min_radius_mm: Optional[float] = typer.Option(None, "--min-radius-mm", help="Smallest panel radius, mm: bounds "
                                            "the micro-plane's curvature bias in U95 and sets what the gross-reading "
                                            "check allows ('inf': flat panels). Default: the layout's [panel] "
                                            "radius_mm, else 500 (named in the verdict as an assumption)."),
        workers: Optional[int] = typer.Option(None, "--workers", help="Run on a new Dask LocalCluster of N worker "
                                              "processes, one task per partition (needs metro[fleet])."),
        scheduler: Optional[str] = typer.Option(None, "--scheduler", help="Run on a running Dask cluster "
                                                "(tcp://host:port), one task per partition (needs metro[fleet])."),
        fail_on_drift: bool = typer.Option(False, "--fail-on-drift", help="Exit 1 on a drift alarm whose change persisted too "
                                           "(by default an alarm is reported, and the exit code judges the holes)."),
        chart_by_panel: bool = typer.Option(False, "--chart-by-panel", help="A new drift-chart baseline at each "
                                            "panel (for panels whose shape moves the redundant reading's misfit); "
                                            "misses a drift slower than a panel."),
        panel: Optional[Path] = typer.Option(None, "--panel", help="The CAD panel the holes are drilled in (STL, OBJ, "
                                             "PLY, GLB; STEP), mm, its frame; with --points: each hole's curvature from "
                                             "it, the normal fitted with the surface known."),
        points: Optional[Path] = typer.Option(None, "--points", help="The hole table (.csv or .parquet: hole_id,x,y,z,"
                                              "i,j,k, mm, panel frame; i,j,k the feed into the panel), joined to the log "
                                              "by hole_id. Alone (no --panel): curvature from the neighbours' normals."),
        position_error_mm: float = typer.Option(0.5, "--position-error-mm", help="With --points: the drill point's "
                                                "position error along the surface, mm (U95: the curvature's change "
                                                "over it)."),
        form_tolerance_mm: float = typer.Option(0.0, "--form-tolerance-mm", help="With --points: the panel's stated "
                                                "form tolerance over the head's footprint, mm (0: the panel is its CAD)."),
        spin_deg: float = typer.Option(None, "--spin-deg", help="With --points, for a log without the robot's pose: the "
                                       "head's spin about the tool axis relative to the panel is within +-SPIN of the "
                                       "cell's convention (TCS x, y near the panel's x, y), deg; in U95. Not given: "
                                       "+-2 where a redundant (4th) reading does not refute the convention (it cannot confirm it: "
                                       "docs/spin.md), else a U95 over every spin."),
        units: Optional[str] = typer.Option(None, "--units", help="Unit of the panel file's and the hole table's "
                                            "coordinates: mm, cm, m or in (overrides what the panel file declares; "
                                            "STL/OBJ/PLY and tables declare none: mm)."),
        follow: bool = typer.Option(False, "--follow", help="A live log (LOG '-' for stdin, or a CSV file): each "
                                    "hole measured as its line arrives; one JSON line per hole on stdout, "
                                    "{\"alarm\": ...} lines for drift alarms, a final {\"summary\": ...}."),
        json_out: bool = typer.Option(False, "--json", help=JSON_HELP + " The summary; per-hole results only with --out."),
        report: Optional[Path] = typer.Option(None, "--report", help=REPORT_HELP),
        qif: Optional[Path] = typer.Option(None, "--qif", help="Also write the per-hole results as a QIF 3.0 "
                                           "Results document (.qif): each hole an angle characteristic with its "
                                           "value, U95 and ISO 14253-1 status; the head and its calibration's "
                                           "SHA-256 as the measurement device."),
        dfq: Optional[Path] = typer.Option(None, "--dfq", help="Also write the per-hole results as a Q-DAS AQDEF "
                                           "file (.dfq) for SPC: one characteristic per hole of the hole table (or "
                                           "one for the log), nominal 0, upper limit the tolerance, deg; the cell as "
                                           "machine, the calibration's SHA-256 as gauge (docs/plant.md)."),
        opcua: Optional[str] = typer.Option(None, "--opcua", help="Also serve each hole's result live on an OPC UA "
                                            "server at opc.tcp://HOST:PORT (OPC 40210 GMS characteristics, a "
                                            "result-ready event per hole, drift alarms as events; needs "
                                            "metro[plant]). A host that is not loopback needs --opcua-cert, "
                                            "--opcua-key and --opcua-users (docs/plant.md)."),
        opcua_cert: Optional[Path] = typer.Option(None, "--opcua-cert", help="The server's certificate (PEM)."),
        opcua_key: Optional[Path] = typer.Option(None, "--opcua-key", help="The certificate's private key (PEM)."),
        opcua_users: Optional[Path] = typer.Option(None, "--opcua-users", help="The users allowed: user:SHA-256-of-"
                                                   "the-password lines."),
        opcua_wait_s: float = typer.Option(0.0, "--opcua-wait-s", help="Wait up to this long for an OPC UA client to "
                                           "subscribe before measuring (a whole log's results go out as measured)."),
        opcua_queue: int = typer.Option(20000, "--opcua-queue", help="Results queued for a client that does not "
                                        "read before its subscription is deleted (a warning; measuring goes on)."),
    ) -> None:
        """Measure every hole of a log: normal, angle to the drill axis with U95, ISO 14253-1 verdict; drift watch.

        Exit code: 0 when every measured hole conforms, 1 when a hole fails, is undecided or has its drilled angle not known (gross readings: re-inspect), or when a drift alarm's change persisted (with --fail-on-drift); 2 on bad input.
        """
        import sys

        from metrology.report.measure import measure_text

        for label, value in (("LOG", None if log == "-" else log), ("--layout", layout), ("--panel", panel),
                             ("--points", points)):
            if value is not None and not Path(value).exists():  # one wording for every input (docs/cli.md)
                fail(f"{value}: no such file ({label})")
            if value is not None and label != "LOG" and Path(value).is_dir():  # a log may be a folder, these not
                fail(f"{value}: a folder, not a file ({label})")
        if workers is not None and scheduler is not None:
            fail("--workers and --scheduler: give one (a new local cluster, or a running one)")
        panel_kw = {"panel": panel, "points": points, "position_error_mm": position_error_mm,
                    "form_tolerance_mm": form_tolerance_mm, "spin_deg": spin_deg, "units": units}
        import contextlib

        server = contextlib.nullcontext()
        if opcua is not None:  # started (and refused: exit 2) before anything is measured
            from metrology.jobs.plant import opcua_server

            server = opcua_server(opcua, tolerance_deg, layout, opcua_cert, opcua_key, opcua_users, warn=warn,
                                  slow_results=opcua_queue)
        if follow:
            if out is not None or report is not None or qif is not None or workers is not None or scheduler is not None \
                    or dfq is not None:
                fail("--follow answers each hole on stdout: no --out, --report, --qif, --dfq, --workers or --scheduler")
            import json as _json

            from metrology.jobs.measure_follow import follow_log

            def emit(obj, flush=True):
                sys.stdout.write(_json.dumps(obj) + "\n")
                if flush:
                    sys.stdout.flush()

            with server as plant:
                _wait_for_client(plant, opcua_wait_s)

                served = []  # the batch's results, handed to the server at once (an alarm sends those before it)

                def on_hole(h):
                    emit(h, flush=False)  # flushed at the end of each batch of lines read together
                    served.append(h)

                def on_batch():
                    sys.stdout.flush()
                    if plant is not None:
                        plant.results(served)
                    served.clear()

                def on_alarm(a):
                    emit({"alarm": a})
                    if plant is not None:
                        plant.results(served)
                        plant.alarm(a)
                    served.clear()

                from metrology.jobs.measure import MeasureOptions

                try:
                    summary = follow_log(log, layout, on_hole, on_alarm, on_batch=on_batch,
                                         options=MeasureOptions(tolerance_deg=tolerance_deg,
                                                                min_radius_mm=min_radius_mm, **panel_kw))
                finally:  # a line in error: the holes answered before it are served too
                    on_batch()
                for note in summary.notes:
                    warn(note)
            emit({"summary": summary.to_dict()})
            bad = summary.counts["fails"] + summary.counts["undecided"] + (len(summary.alarms) if fail_on_drift else 0)
            raise typer.Exit(1 if bad else 0)
        import dataclasses

        from metrology.jobs.measure import MeasureOptions

        options = MeasureOptions(out=out, tolerance_deg=tolerance_deg, min_radius_mm=min_radius_mm, workers=workers,
                                 scheduler=scheduler, report_html=report, command=invocation(ctx),
                                 fail_on_drift=fail_on_drift, chart_by_panel=chart_by_panel, qif=qif, dfq=dfq,
                                 per_hole=not (json_out and out is None), **panel_kw)
        if log == "-":
            import shutil
            import tempfile

            tmp = Path(tempfile.mkdtemp(prefix="metro-stdin-"))
            try:
                path = tmp / "stdin.csv"
                with open(path, "wb") as fh:
                    shutil.copyfileobj(sys.stdin.buffer, fh)
                if path.stat().st_size == 0:
                    fail("LOG -: nothing on stdin")
                with server as plant:
                    _wait_for_client(plant, opcua_wait_s)
                    rep = _run(path, layout, dataclasses.replace(options, log_display="<stdin>", plant=plant))
            finally:
                shutil.rmtree(tmp, ignore_errors=True)
        else:
            with server as plant:
                _wait_for_client(plant, opcua_wait_s)
                rep = _run(log, layout, dataclasses.replace(options, plant=plant))
        if json_out:
            echo_json(rep.to_dict(), "measure")
        else:
            text = measure_text(rep)
            lines = [ln for ln in text.splitlines() if not ln.startswith("warning: ")]  # warnings went to warn()
            typer.echo("\n".join(lines), err=out is None)
        reported(report)
        finish(rep.verdict)

    def _wait_for_client(plant, wait_s):
        if plant is not None and wait_s > 0 and not plant.wait_for_client(wait_s):
            warn(f"--opcua-wait-s {wait_s:g}: no OPC UA client subscribed; measuring")

    def _run(log, layout, options):
        from metrology.jobs.measure import measure_files
        from metrology.measure.run import tune_allocator

        tune_allocator()  # this process is metro's: glibc's heap kept for the batches (its docstring)
        with progress_bar("measure") as progress:
            return measure_files(log, layout, options, warn=warn, progress=progress)
