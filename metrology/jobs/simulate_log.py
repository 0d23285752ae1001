"""``metro simulate-log``'s job: a calibrated layout in, a production hole log with its truth out.

The log is drawn by the independent forward simulator (:mod:`metrology.sim.forward.log`): the
cell adjusts its attitude with the calibrated layout (``--layout``) while its beams are those of
the true layout (``--true-layout``; else, when the calibrated layout carries its covariance, a
head drawn from it, ``theta ~ N(0, C)`` added to its zero points and beam tilts: a head as its
calibration says it may be; else, or with ``layout_error_mm``/``layout_error_deg`` given, the
calibrated one with each zero point moved by ``U(0.5, 1) layout_error_mm`` mm and each beam turned
by ``U(0.5, 1) layout_error_deg`` deg; drawn from the seed).

The panel (``panel``): ``flat``, ``sphere``, ``cylinder`` (closed-form, :mod:`metrology.sim.forward.panels`;
a cylinder's axis at ``azimuth_deg`` from the panel's ``x`` in its ``xy`` plane, default along ``y``),
a generated panel ``wing``, ``barrel``, ``nacelle``, ``saddle`` (:mod:`metrology.sim.forward.shapes`),
or a file (STL, OBJ, PLY, GLB, STEP; :func:`metrology.sim.forward.meshes.load_sim_panel`). ``points``:
a hole table drilled in order, cycled. ``off_cad``: the true panel off the CAD one (a dent, a
spring-back, a shift). ``controller``: ``microplane`` (the cell's plane fit) or ``metro``: the
measurement's own corrected normal, :func:`metro_controller`, the only place the simulation
reaches into :mod:`metrology.measure` (the forward package itself never does).
"""

from __future__ import annotations

import math
import re
import time
from pathlib import Path

__all__ = ["simulate_log_files", "parse_drift", "parse_shift", "parse_range", "default_truth_path", "make_log_panel",
           "metro_controller", "CONTROLLERS"]

#: without a covariance in the layout: the drawn head's zero error (mm) and beam error (deg)
DEFAULT_LAYOUT_ERROR = 0.03
#: the random stream of the drawn true layout: ``SeedSequence(seed, spawn_key=(LAYOUT_STREAM,))``
#: (the holes use 2-element keys, so the streams never meet)
LAYOUT_STREAM = 2**32 - 1

_FAULT = re.compile(r"^(?:(?P<cell>[^/:@]+)/)?(?P<sensor>[^/:@]+):(?P<value>[^@]+)(?:@(?P<hole>.+))?$")


def _number(text, option, value, what):
    try:
        x = float(text)
    except ValueError:
        raise ValueError(f"{option} {value}: {what} {text!r} is not a number") from None
    if not math.isfinite(x):
        raise ValueError(f"{option} {value}: {what} must be finite")
    return x


def _hole(text, option, value):
    try:
        k = int(text)
    except ValueError:
        raise ValueError(f"{option} {value}: hole {text!r} is not a whole number") from None
    if k < 1:
        raise ValueError(f"{option} {value}: hole {k} must be 1 or more (holes count from 1)")
    return k - 1


def parse_drift(value: str):
    """``[CELL/]SENSOR:MM_PER_HOUR[@HOLE]`` (HOLE counts from 1; default 1) -> SensorDrift."""
    from metrology.sim.forward.log_spec import SensorDrift

    m = _FAULT.match(value.strip())
    if not m:
        raise ValueError(f"--drift {value}: expected [CELL/]SENSOR:MM_PER_HOUR[@HOLE], e.g. L2:0.002@5000")
    rate = _number(m["value"], "--drift", value, "rate")
    start = 0 if m["hole"] is None else _hole(m["hole"], "--drift", value)
    return SensorDrift(m["sensor"], rate, "hour", start, m["cell"])


def parse_shift(value: str):
    """``[CELL/]SENSOR:MM@HOLE`` (HOLE counts from 1) -> SensorShift."""
    from metrology.sim.forward.log_spec import SensorShift

    m = _FAULT.match(value.strip())
    if not m or m["hole"] is None:
        raise ValueError(f"--shift {value}: expected [CELL/]SENSOR:MM@HOLE, e.g. L3:0.05@20000")
    return SensorShift(m["sensor"], _number(m["value"], "--shift", value, "size"),
                       _hole(m["hole"], "--shift", value), m["cell"])


def parse_range(value: str, option: str, lo_bound: float = -math.inf) -> tuple:
    """``MIN,MAX`` -> (min, max) floats with ``lo_bound <= min <= max``."""
    parts = value.split(",")
    if len(parts) != 2:
        raise ValueError(f"{option} {value}: expected MIN,MAX")
    lo, hi = (_number(p, option, value, "bound") for p in parts)
    if not (lo_bound <= lo <= hi):
        raise ValueError(f"{option} {value}: expected {lo_bound:g} <= MIN <= MAX")
    return lo, hi


def default_truth_path(out) -> Path:
    """``log.csv`` -> ``log.truth.csv``; ``log.parquet`` -> ``log.truth.parquet``; a folder ``logs``
    -> ``logs.truth.parquet`` beside it."""
    p = Path(str(out).rstrip("/\\"))
    if p.suffix.lower() in (".csv", ".parquet") and not str(out).endswith(("/", "\\")):
        return p.with_name(p.stem + ".truth" + p.suffix.lower())
    return p.with_name(p.name + ".truth.parquet")


class _MetroController:
    """``--controller metro``: ``metrology.measure.surface.surface_normal(layout, d, shape)``, imported
    when first called (the measurement side's contract: ``layout`` the cell's SensorLayout, ``d (h, n)``
    mm readings (NaN blank), ``shape (h, 3, 3)`` 1/mm TCS the CAD's shape operator, positive where the
    surface bends away from the head; returns the unit normal ``(h, 3)`` TCS toward the head and ``ok (h,)``)."""

    name = "metro"
    wants_shape = True
    wants_temperature = True  # the head's temperature, for a layout's temperature coefficient

    def __init__(self):
        self._fn = None

    def load(self):
        if self._fn is None:
            try:
                from metrology.measure.surface import surface_normal as _plain  # noqa: F401 (the contract's home)
                from metrology.measure.effects import surface_normal  # it, the layout's head terms applied
            except ImportError as exc:
                raise ValueError(f"--controller metro: metrology.measure.surface.surface_normal is not available "
                                 f"({exc})") from None
            self._fn = surface_normal
        return self._fn

    def __call__(self, layout, d, shape, temp_c=None):
        return self.load()(layout, d, shape, temp_c)


def metro_controller():
    """The ``metro`` controller (see :class:`_MetroController`), checked to be importable."""
    c = _MetroController()
    c.load()
    return c


def _microplane():
    from metrology.sim.forward.log import MicroPlane

    return MicroPlane()


#: ``--controller`` names -> factories
CONTROLLERS = {"microplane": _microplane, "metro": metro_controller}


def make_log_panel(panel, radius_mm=None, azimuth_deg=None, off_cad=None, table=None):
    """``(truth, cad)`` panels of ``--panel`` (a name or a file), ``--radius-mm``, ``--azimuth-deg``, ``--off-cad``;
    a mesh file is turned to face the head (the side ``table``'s feeds come from; without one, ``+z``)."""
    from metrology.sim.forward.panels import PANELS, make_panel
    from metrology.sim.forward.shapes import GENERATED, generated_panel, parse_off_cad

    if azimuth_deg is not None and panel != "cylinder":
        raise ValueError(f"--azimuth-deg {azimuth_deg:g}: only a cylinder has an axis (got --panel {panel})")
    if panel in PANELS:
        axis = (0.0, 1.0, 0.0)
        if azimuth_deg is not None:
            if not math.isfinite(azimuth_deg):
                raise ValueError(f"--azimuth-deg {azimuth_deg}: expected a finite angle")
            az = math.radians(azimuth_deg)
            axis = (math.cos(az), math.sin(az), 0.0)
        cad = make_panel(panel, radius_mm, axis)
    elif panel in GENERATED:
        if radius_mm is not None:
            raise ValueError(f"--radius-mm: the generated panel {panel} has its own radii")
        cad = generated_panel(panel)
    elif Path(panel).suffix:
        from metrology.sim.forward.meshes import load_sim_panel

        if radius_mm is not None:
            raise ValueError(f"--radius-mm: a panel file ({panel}) has its own shape")
        from metrology.sim.forward.meshes import MeshPanel

        cad = load_sim_panel(panel)[1]
        if isinstance(cad, MeshPanel):
            cad = cad.oriented(*(() if table is None else (table.points, table.feed)))
    else:
        raise ValueError(f"--panel {panel}: expected one of {', '.join([*PANELS, *GENERATED])} or a panel file "
                         "(.stl, .obj, .ply, .glb, .step)")
    truth = cad if off_cad is None else parse_off_cad(off_cad, cad)
    return truth, cad


def _check_units(layout, panel, cad, table, points) -> None:
    """A panel file and its hole table that do not read as mm against the head: one line, ValueError
    (:func:`metrology.io.panel_units.check_panel_units`, as ``metro measure`` checks them)."""
    import numpy as np

    from metrology.io.panel_units import check_panel_units
    from metrology.jobs.measure_panel import footprint_mm, standoff_mm

    V = getattr(cad, "V", None)
    is_file = Path(str(panel)).suffix != "" and V is not None
    if not is_file and table is None:
        return
    names = " and ".join(str(p) for p in ((panel if is_file else None), points) if p is not None)
    line = check_panel_units(footprint_mm(layout), standoff_mm(layout),
                             panel_extent=None if not is_file else np.ptp(np.asarray(V, float), axis=0),
                             table_points=None if table is None else table.points, names=names,
                             units_option=False)
    if line is not None:
        raise ValueError(line)


def _layouts(layout_path, true_layout_path, seed, layout_error_mm, layout_error_deg):
    import numpy as np

    from metrology.io.layout import load_layout
    from metrology.sim.forward.head import perturb_layout

    cell = load_layout(layout_path)
    if true_layout_path is not None:
        true = load_layout(true_layout_path)
        if tuple(true.names) != tuple(cell.names):
            raise ValueError(f"{true_layout_path}: sensors {list(true.names)} differ from {layout_path}'s "
                             f"{list(cell.names)}")
        return cell, true
    rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(LAYOUT_STREAM,)))
    if layout_error_mm is None and layout_error_deg is None and cell.covariance is not None:
        from metrology.core.model import direction_basis

        t = cell.effects  # a head with terms: its sensors and terms drawn jointly (their joint covariance)
        full = cell.covariance if t is None else np.block([[cell.covariance, t.cross], [t.cross.T, t.cov]])
        draw = rng.multivariate_normal(np.zeros(len(full)), full, method="eigh")
        theta = draw[:5 * cell.n].reshape(cell.n, 5)
        u = cell.direction + np.einsum("nk,nkj->nj", theta[:, 3:], direction_basis(cell.direction))
        true = cell.with_params(cell.zero + theta[:, :3], u / np.linalg.norm(u, axis=1, keepdims=True))
        if t is not None:
            from dataclasses import replace

            vals, j = [], 5 * cell.n
            for c in t.components:
                vals.append(c.with_values(c.values + draw[j:j + c.n_params]))
                j += c.n_params
            true = replace(true, effects=replace(t, components=tuple(vals)))
        return cell, true
    layout_error_mm = DEFAULT_LAYOUT_ERROR if layout_error_mm is None else layout_error_mm
    layout_error_deg = DEFAULT_LAYOUT_ERROR if layout_error_deg is None else layout_error_deg
    if layout_error_mm < 0 or layout_error_deg < 0:
        raise ValueError("--layout-error-mm and --layout-error-deg must be >= 0")
    true = perturb_layout(rng, cell, (0.5 * layout_error_mm, layout_error_mm),
                          (0.5 * layout_error_deg, layout_error_deg))
    return cell, true


def simulate_log_files(layout_path, out, *, truth=None, true_layout_path=None, holes=10_000, cells=1,
                       panel="flat", radius_mm=None, noise_mm=None, angle_deg=(0.5, 5.0), standoff_mm=None,
                       spin_deg=0.0, patch_mm=400.0, holes_per_hour=600.0, drifts=(), shifts=(), gross_rate=0.0,
                       layout_error_mm=None, layout_error_deg=None, seed=0, write_truth=True, progress=None,
                       points=None, controller="microplane", azimuth_deg=None, off_cad=None) -> dict:
    """Write a simulated log at ``out`` (``.csv``, ``.parquet``: one file; else a new folder of partitioned Parquet)
    and its truth at ``truth`` (default :func:`default_truth_path`; none when ``write_truth`` is False,
    e.g. for a throughput run); returns the summary.

    ``drifts``/``shifts`` are SensorDrift/SensorShift (:func:`parse_drift`, :func:`parse_shift`);
    angles are in degrees (the edge), lengths in mm. ``points`` a hole table (``hole_id,x,y,z,i,j,k``);
    ``controller`` a key of :data:`CONTROLLERS`. Everything is checked before a file is written.
    """
    from metrology.sim.forward.log import BLOCK_HOLES, simulate_log
    from metrology.sim.forward.log_spec import LogSpec
    from metrology.sim.head_terms import properties_from_terms
    from metrology.sim.forward.log_write import LOG_FORMATS, check_log_output
    if not write_truth and truth is not None:
        raise ValueError("--truth and --no-truth exclude each other")
    truth = None if not write_truth else default_truth_path(out) if truth is None else Path(truth)
    kind = check_log_output(out, truth)
    if holes < 1 or cells < 1 or holes < cells:
        raise ValueError(f"--holes {holes} --cells {cells}: expected holes >= cells >= 1")
    cell, true = _layouts(layout_path, true_layout_path, seed, layout_error_mm, layout_error_deg)
    if noise_mm is None and not all(math.isfinite(x) for x in true.noise_mm):
        raise ValueError(f"{true_layout_path or layout_path}: no noise_mm for every sensor; give --noise-mm")
    if standoff_mm is None and not all(math.isfinite(x) for x in true.range_mm.ravel()):
        raise ValueError(f"{true_layout_path or layout_path}: no range_mm for every sensor; give --standoff-mm")
    if controller not in CONTROLLERS:
        raise ValueError(f"--controller {controller}: expected one of {', '.join(CONTROLLERS)}")
    table = None
    if points is not None:
        from metrology.sim.forward.holes import read_hole_table

        table = read_hole_table(points)
    elif off_cad is not None:
        raise ValueError("--off-cad needs --points: a panel off its CAD is seen at the table's nominal holes")
    truth_panel, cad_panel = make_log_panel(panel, radius_mm, azimuth_deg, off_cad, table)
    _check_units(cell, panel, cad_panel, table, points)
    control = CONTROLLERS[controller]()
    spec = LogSpec(true, cell, truth_panel, angle_rad=tuple(math.radians(a) for a in angle_deg),
                   noise_mm=noise_mm, standoff_mm=standoff_mm, spin_rad=math.radians(spin_deg),
                   patch_half_mm=patch_mm / 2, holes_per_hour=holes_per_hour, drifts=tuple(drifts),
                   shifts=tuple(shifts), gross_rate=gross_rate, table=table,
                   cad_panel=None if cad_panel is truth_panel else cad_panel,
                   controller=None if controller == "microplane" else control,
                   properties=properties_from_terms(true if true.effects is not None else cell))
    done = {"n": 0}

    def chunks():
        for chunk in simulate_log(spec, seed, holes, cells, chunk_holes=8 * BLOCK_HOLES):
            done["n"] += chunk.n
            if progress is not None:
                progress(done["n"], holes, f"{chunk.cell}")
            yield chunk

    t0 = time.perf_counter()
    written = LOG_FORMATS[kind](chunks(), out, truth)
    seconds = time.perf_counter() - t0
    n, files = written if kind == "parquet" else (written, [Path(out)])
    return {"out": str(out), "format": kind, "truth": None if truth is None else str(truth), "holes": n,
            "cells": cells, "files": len(files), "seed": seed, "seconds": seconds, "holes_per_s": n / seconds if seconds > 0 else None,
            "true_layout": str(true_layout_path) if true_layout_path else "drawn from --layout and the seed",
            "spec": spec.to_dict()}
