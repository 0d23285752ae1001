"""``metro demo``: the bundled walk-through, one command line per step."""

from __future__ import annotations

import shlex
from pathlib import Path

from metrology.core.progress import notify

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
    ("4. Diagnose a measured data set that hides an effect the simple model lacks",
     "diagnose {fx}/hidden/export.csv --plane {fx}/hidden/plane.json --layout {fx}/hidden/layout.toml "
     "--report {out}/diagnose"),
    ("5. Micro-plane against micro-sphere normals on a curved panel (R = 800 mm)",
     "normals {fx}/panel_cyl800.stl --layout {fx}/layout_table6.toml --grid 40 --tilt-deg 2 --seed 1 "
     "--plot {out}/panel_errors.png"),
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


def run_demo(fixtures, out, run_step, announce=print, progress=None) -> int:
    """Run :data:`DEMO_STEPS` on the fixtures, writing into ``out``.

    Parameters
    ----------
    fixtures : str or os.PathLike
        The bundled fixtures directory (holds ``measured/``).
    out : str or os.PathLike
        Output directory, created if absent.
    run_step : callable
        ``run_step(args) -> int``: runs one ``metro`` command line (list of str), returns
        its exit code (0 or None on success).
    announce : callable
        ``announce(title, args)``, called before each step.
    progress : callable or None
        ``progress(done, total, what)`` before each step (:mod:`metrology.core.progress`).

    Returns
    -------
    int
        0, or the exit code of the first failing step (the steps after it are not run).

    Raises
    ------
    ValueError
        ``fixtures`` does not hold the bundled fixtures.
    """
    fixtures, out = Path(fixtures), Path(out)
    if not (fixtures / "measured").is_dir():
        raise ValueError(f"{fixtures}: bundled fixtures not found (expected measured/, hidden/ and the layouts; "
                         "omit --fixtures to use the data shipped with metro)")
    out.mkdir(parents=True, exist_ok=True)
    for k, (title, line) in enumerate(DEMO_STEPS):
        args = shlex.split(line.format(fx=fixtures, out=out))
        notify(progress, k, len(DEMO_STEPS), f"step {title.split(' ', 1)[0]} metro {args[0]}")
        announce(title, args)
        rc = run_step(args)
        if rc:  # a failing step has printed its one-line error
            return rc
    notify(progress, len(DEMO_STEPS), len(DEMO_STEPS), "done")
    return 0
