"""``metro demo``: the bundled walk-through, one command line per step."""

from __future__ import annotations

import shlex
from pathlib import Path

from metrology.core.progress import notify
from metrology.core.verdict import EXIT_FAILED

__all__ = ["DEMO_STEPS", "run_demo"]

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
    ("4. Diagnose a measured data set that hides an effect the simple model lacks; write it into the layout",
     "diagnose {fx}/hidden/export.csv --plane {fx}/hidden/plane.json --layout {fx}/hidden/layout.toml "
     "--report {out}/diagnose --out {out}/extended.toml"),
    ("4b. Calibrate that head with the term diagnose named, jointly (its U on the certificate)",
     "calibrate {fx}/hidden/export.csv --plane {fx}/hidden/plane.json --layout {out}/extended.toml "
     "--out {out}/calibrated_extended.toml"),
    ("5. Micro-plane against micro-sphere normals on a curved panel (R = 800 mm)",
     "normals {fx}/panel_cyl800.stl --layout {fx}/layout_table6.toml --grid 40 --tilt-deg 2 --seed 1 "
     "--plot {out}/panel_errors.png"),
    ("6. Simulate a production log: 5000 holes drilled with that head (its temperature coefficient drawn), "
     "L3 knocked at hole 3000",
     "simulate-log --layout {out}/calibrated_extended.toml --holes 5000 --shift L3:0.015@3000 --seed 1 "
     "--out {out}/hole_log.csv"),
    ("7. Measure every hole on the flat panel with the head's term removed from every reading (its covariance in "
     "U95): angle to the drill axis with U95, verdict, drift watch",
     "measure {out}/hole_log.csv --layout {out}/calibrated_extended.toml --min-radius-mm inf --out {out}/holes.csv"),
)


def new_output_dir(base="metro-demo") -> Path:
    """A folder for the demo's outputs that holds nothing yet: ``base`` if it is absent or
    empty, else ``base-2``, ``base-3``, ... (a second run never overwrites the first)."""
    base = Path(base)
    k = 1
    cand = base
    while cand.exists() and (not cand.is_dir() or any(cand.iterdir())):
        k += 1
        cand = base.with_name(f"{base.name}-{k}")
    return cand


#: with ``--report``: each step's own HTML report, in ``out`` (None: the step writes no report)
STEP_REPORTS = ("fit-plane.html", "calibrate.html", "validate.html", "diagnose.html", "calibrate-extended.html",
                "normals.html", None, "measure.html")


def _with_report(args, path):
    """``args`` with ``--report path`` (replacing a ``--report`` already there)."""
    args = list(args)
    if "--report" in args:
        args[args.index("--report") + 1] = str(path)
    else:
        args += ["--report", str(path)]
    return args


def run_demo(fixtures, out, run_step, announce=print, report=None, command=None, progress=None) -> int:
    """Run :data:`DEMO_STEPS` on the fixtures, writing into ``out``.

    Parameters
    ----------
    fixtures : str or os.PathLike
        The bundled fixtures directory (holds ``measured/``).
    out : str or os.PathLike
        Output directory, created if absent.
    run_step : callable
        ``run_step(args) -> int``: runs one ``metro`` command line (list of str), returns
        its exit code (0 or None: passed; 1: ran, its verdict failed; 2: bad input).
    announce : callable
        ``announce(title, args)``, called before each step.
    progress : callable or None
        ``progress(done, total, what)`` before each step (:mod:`metrology.core.progress`).
    report : str or os.PathLike or None
        One HTML report of every step (each step also writes its own, :data:`STEP_REPORTS`
        in ``out``, linked from it); ``command`` is the command line it names (None: this
        process's).

    Returns
    -------
    int
        0 when every step passed; 1 when every step ran and a verdict failed; otherwise the
        exit code of the first step that could not run (the steps after it are not run).

    Raises
    ------
    ValueError
        ``fixtures`` does not hold the bundled fixtures.
    """
    from metrology.report.html import check_report_path, collect

    fixtures, out = Path(fixtures), Path(out)
    if not (fixtures / "measured").is_dir():
        raise ValueError(f"{fixtures}: bundled fixtures not found (expected measured/, hidden/ and the layouts; "
                         "omit --fixtures to use the data shipped with metro)")
    if report is not None:
        check_report_path(report)
    out.mkdir(parents=True, exist_ok=True)
    worst = 0
    with collect() as pages:
        for k, ((title, line), name) in enumerate(zip(DEMO_STEPS, STEP_REPORTS)):
            args = shlex.split(line.format(fx=fixtures, out=out))
            if report is not None and name is not None:
                args = _with_report(args, out / name)
            notify(progress, k, len(DEMO_STEPS), f"step {title.split(' ', 1)[0]} metro {args[0]}")
            announce(title, args)
            rc = run_step(args) or 0
            if rc and rc != EXIT_FAILED:  # a step that could not run has printed its one-line error
                return rc
            worst = max(worst, rc)
    notify(progress, len(DEMO_STEPS), len(DEMO_STEPS), "done")
    if report is not None:
        _write_demo_report(report, pages, [out / name for name in STEP_REPORTS if name is not None], command)
    return worst


def _write_demo_report(report, pages, step_files, command):
    """One report of the steps' pages, each section linked to its step's own report."""
    import os
    from dataclasses import replace

    from metrology.report.html import RunInfo, run_info, write_report

    sections, inputs, seen = [], [], set()
    base = Path(report).resolve().parent
    for (_, run, secs), f in zip(pages, step_files):
        link = os.path.relpath(Path(f).resolve(), base)
        sections += [replace(s, link=link) for s in secs]
        for row in run.inputs:
            if row[1] not in seen:
                seen.add(row[1])
                inputs.append((f"{row[0]} ({run.command.split()[1]})",) + tuple(row[1:]))
    run = run_info({}, command)
    write_report(report, "metro demo: fit-plane, calibrate, validate, diagnose, calibrate, normals, simulate-log, measure",
                 RunInfo(run.command, tuple(inputs), run.versions, None, run.written), sections)
