"""Synthetic calibration runs that hide an effect: exports in the public CSV format.

A run is drawn with :func:`metrology.simulation.random_poses` (the typical pose set of
metro: stand-off 40-60 mm, tilt up to 5 deg, spots over a 200 mm square), a clock and a
thermometer (:func:`warmup`), and readings from the true sensors plus, for each hidden
effect, the *same* component of :mod:`metrology.core.effects` that the diagnosis fits, evaluated
on the true geometry, plus the layout's own head terms (drawn by the forward simulator's
physics), plus white Gaussian noise of the layout's ``noise_mm``.

``size`` of each effect (:data:`SIZE_MEANING`):

``scale``         gain error ``k`` (unitless; 1e-3 = 0.1 %)
``incidence``     ``c`` mm (the bias at 45 deg incidence)
``drift``         ``r`` mm/K, with the temperature of the warm-up
``nonlinearity``  ``c3`` mm; ``c2 = c3 / 2`` (an asymmetric S over the range)
``plane_form``    bow ``b_ss = size``, ``b_st = 0.3 size``, ``b_tt = -0.5 size`` mm at 100 mm
``pose_error``    1-sigma error of the recorded TCS position, per axis, mm
``outliers``      3 gross readings of +-``size`` mm on the sensor
``periodic``      OUTSIDE the catalogue: ``size sin(2 pi j / 6.5 + phi)`` mm in pose index ``j``
                  (a cyclic error of a drive, say), for testing that it is not named
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from metrology.core.effects import REGISTRY, Covariates
from metrology.io.export import TrackerExport
from metrology.core.layout import SensorLayout
from metrology.core.model import readings
from metrology.core.plane import Plane
from metrology.sim.simulation import PoseSpec, random_poses

__all__ = ["HiddenEffect", "SIZE_MEANING", "EFFECTS", "SETUP_EFFECTS", "OUTSIDE", "warmup", "synth_run", "synth_cloud",
           "typical_layouts", "TYPICAL_NOISE_MM", "TYPICAL_RANGE_MM", "N_OUTLIERS", "PERIOD_POSES"]

SIZE_MEANING = {name: cls.size_meaning for name, cls in REGISTRY.items()}
SIZE_MEANING["periodic"] = "amplitude mm of a cyclic error in pose index (outside the catalogue)"
EFFECTS = tuple(k for k in SIZE_MEANING if k != "periodic")
SETUP_EFFECTS = tuple(name for name, cls in REGISTRY.items() if cls.setup)
OUTSIDE = ("periodic",)
N_OUTLIERS = 3
PERIOD_POSES = 6.5
#: the simulated tracker scan of the datum: points, half-width of the square (mm), noise (mm)
CLOUD_POINTS = 4000
CLOUD_HALF_WIDTH_MM = 150.0
CLOUD_NOISE_MM = 0.010
#: the typical sensors: 3 um repeatability (the paper's R = 9e-6 mm^2), 30-70 mm range
TYPICAL_NOISE_MM = 0.003
TYPICAL_RANGE_MM = (30.0, 70.0)


@dataclass(frozen=True)
class HiddenEffect:
    """An effect to hide: ``name`` (catalogue or :data:`OUTSIDE`), ``sensor`` name (None for
    an effect of the set-up) and ``size`` (see :data:`SIZE_MEANING`)."""

    name: str
    sensor: str | None
    size: float

    def __post_init__(self):
        if self.name not in SIZE_MEANING:
            raise ValueError(f"unknown effect {self.name!r}, expected one of {', '.join(SIZE_MEANING)}")
        if self.name in SETUP_EFFECTS and self.sensor is not None:
            raise ValueError(f"{self.name} is an effect of the set-up: give no sensor")
        if self.name not in SETUP_EFFECTS and self.sensor is None:
            raise ValueError(f"{self.name} acts on one sensor: name it")
        if not np.isfinite(self.size):
            raise ValueError(f"effect size must be finite, got {self.size}")


def typical_layouts(noise_mm=TYPICAL_NOISE_MM, range_mm=TYPICAL_RANGE_MM):
    """(nominal, true) layouts: the paper's Table 6 foot with its estimated errors as truth."""
    from metrology.core.paper import table6_layouts

    nominal, true = table6_layouts()
    n = nominal.n
    noise = np.full(n, float(noise_mm))
    rng = np.tile(np.asarray(range_mm, float), (n, 1))
    return (SensorLayout(nominal.names, nominal.zero, nominal.direction, noise, rng),
            SensorLayout(true.names, true.zero, true.direction, noise, rng))


def warmup(rng: np.random.Generator, n_poses: int, dt_s=(20.0, 40.0), start_c=20.0, rise_k=4.0,
           tau_s=900.0, jitter_k=0.02):
    """Times and temperatures of a run that starts cold.

    Returns
    -------
    time_s : (p,) float, s, from 0, steps uniform in ``dt_s``
    temp_c : (p,) float, deg C: ``start + rise (1 - exp(-t / tau))`` plus Gaussian jitter
    """
    t = np.concatenate([[0.0], np.cumsum(rng.uniform(*dt_s, size=n_poses - 1))])
    temp = start_c + rise_k * (1.0 - np.exp(-t / tau_s)) + rng.normal(0.0, jitter_k, n_poses)
    return t, temp


def _component(effect: HiddenEffect, i):
    if effect.name not in REGISTRY:
        raise ValueError(effect.name)
    return REGISTRY[effect.name].hidden(i, effect.size)


#: how many times :func:`synth_run` redraws the poses that read out of the sensors' range before it
#: says it cannot keep them in range (each redraw takes the poses still out: a few suffice)
MAX_REDRAWS = 50


def _readings_of(rng, lt, plane, poses, time_s, temp_c, effects):
    """The readings of ``poses`` with ``effects`` hidden and noise: ``(poses, d, trans, truth)``."""
    n_poses = len(poses.tcs2tracker_rot)
    N, D = poses.plane_in_tcs(plane.normal, plane.offset)
    d0, valid = readings(lt.zero, lt.direction, N, D)
    if not np.all(valid):
        raise ValueError("simulated beams miss the datum: check the pose distribution")
    centre = -plane.offset * plane.normal  # the centre of the spot spread (random_poses)
    cov = Covariates.from_geometry(lt.zero, lt.direction, N, D, poses.tcs2tracker_rot, poses.tcs2tracker_trans,
                                   plane.normal, centre, lt.range_mm, time_s, temp_c)
    d = d0.copy()
    trans = poses.tcs2tracker_trans.copy()
    truth = {"effects": []}
    for e in effects:
        i = None if e.sensor is None else lt.names.index(e.sensor)
        rec = {"name": e.name, "sensor": e.sensor, "size": e.size}
        if e.name == "pose_error":
            trans = trans + rng.normal(0.0, e.size, trans.shape)
            rec["sigma_along_normal_mm"] = e.size
        elif e.name == "outliers":
            rows = rng.choice(n_poses, size=N_OUTLIERS, replace=False)
            signs = rng.choice([-1.0, 1.0], size=N_OUTLIERS)
            d[rows, i] += signs * e.size
            rec["poses"] = sorted(int(r) for r in rows)
        elif e.name == "periodic":
            phase = rng.uniform(0, 2 * np.pi)
            d[:, i] += e.size * np.sin(2 * np.pi * np.arange(n_poses) / PERIOD_POSES + phase)
        else:
            comp = _component(e, i)
            d += comp.evaluate(comp.values, d0, cov)
            rec["values"] = dict(zip(comp.param_names, comp.values.tolist()))
        truth["effects"].append(rec)
    if lt.effects is not None:  # the layout's head terms, as the forward simulator's physics
        from metrology.sim.head_terms import properties_from_terms

        angle = np.arccos(np.clip(cov.cos_inc, 0.0, 1.0))
        d += properties_from_terms(lt).offsets(d0, angle, temp_c)
        truth["terms"] = [{"label": c.label, "values": dict(zip(c.param_names, np.asarray(c.values).tolist()))}
                          for c in lt.effects.components]
    d += rng.normal(0.0, 1.0, d.shape) * lt.noise_mm[None, :]
    return poses, d, trans, truth


def synth_run(rng: np.random.Generator, layout_true: SensorLayout, plane: Plane, n_poses: int,
              effects=(), spec: PoseSpec = PoseSpec()):
    """A synthetic run of ``n_poses`` poses hiding ``effects``.

    Parameters
    ----------
    rng : numpy.random.Generator
    layout_true : SensorLayout, the true sensors; ``noise_mm`` (finite) is the reading noise and
        ``range_mm`` the linearity range; its head terms (``effects``), if any, act on every reading as
        the forward simulator's physics (:func:`metrology.sim.head_terms.properties_from_terms`: a gain
        of the true distance, a bias of the true incidence on the datum, a coefficient of the
        warm-up's temperature, a characteristic), listed in ``truth["terms"]``
    plane : Plane, tracker frame, the datum's mean plane (the form, if any, is added to it)
    n_poses : int
    effects : sequence of HiddenEffect
    spec : PoseSpec

    Returns
    -------
    export : TrackerExport, recorded poses (with any pose error) and readings
    truth : dict, what was hidden: per effect the component's parameter values
    """
    from metrology.core.frames import quaternion_from_matrix

    if not np.all(np.isfinite(layout_true.noise_mm)):
        raise ValueError("the layout must state noise_mm for every sensor to simulate readings")
    if n_poses < 10:
        raise ValueError(f"need at least 10 poses, got {n_poses}")
    effects = tuple(effects)
    for e in effects:
        if e.sensor is not None and e.sensor not in layout_true.names:
            raise ValueError(f"effect {e.name}: sensor {e.sensor!r} not in the layout ({', '.join(layout_true.names)})")
    poses = random_poses(rng, layout_true, plane.normal, plane.offset, n_poses, spec)
    time_s, temp_c = warmup(rng, n_poses)
    lt = layout_true
    lo, hi = lt.range_mm[:, 0], lt.range_mm[:, 1]
    for attempt in range(MAX_REDRAWS + 1):
        poses, d, trans, truth = _readings_of(rng, lt, plane, poses, time_s, temp_c, effects)
        out = np.isfinite(d) & ((d < lo) | (d > hi))  # the sensors' own data are not valid there
        bad = np.flatnonzero(out.any(1))
        if not bad.size:
            break
        if attempt == MAX_REDRAWS:
            p, i = bad[0], int(np.flatnonzero(out[bad[0]])[0])
            hidden = ", ".join(f"{e.name} of size {e.size:g}" for e in effects) or "no effect"
            raise ValueError(f"cannot keep the simulated poses in the sensors' range: after {MAX_REDRAWS} redraws "
                             f"{bad.size} of {n_poses} poses still read out of range (pose P{p + 1:03d}: "
                             f"d_{lt.names[i]} = {d[p, i]:.4f} mm, range [{lo[i]:g}, {hi[i]:g}] mm) with {hidden}: "
                             f"a smaller --size, or a layout whose range_mm holds the stand-off")
        # redraw the poses that read out of range: a run in range keeps its poses (same seed, same bytes)
        new = random_poses(rng, lt, plane.normal, plane.offset, bad.size, spec)
        rot, tr = poses.tcs2tracker_rot.copy(), poses.tcs2tracker_trans.copy()
        rot[bad], tr[bad] = new.tcs2tracker_rot, new.tcs2tracker_trans
        poses = type(poses)(rot, tr)
    quat = quaternion_from_matrix(poses.tcs2tracker_rot)
    export = TrackerExport(tuple(f"P{j + 1:03d}" for j in range(n_poses)), time_s, temp_c, quat, trans,
                           lt.names, d)
    return export, truth


def synth_cloud(rng: np.random.Generator, plane: Plane, effects=(), n_points=CLOUD_POINTS,
                half_width_mm=CLOUD_HALF_WIDTH_MM, noise_mm=CLOUD_NOISE_MM):
    """A tracker scan of the datum of :func:`synth_run`: points uniform over a square of
    ``2 half_width_mm`` around the datum centre, displaced along the normal by the datum's
    form (the ``plane_form`` effect among ``effects``, if any: the same surface the beams
    see) plus Gaussian noise of ``noise_mm`` along the normal.

    Returns
    -------
    points : (n_points, 3) float, mm, tracker frame
    """
    from metrology.core.plane import plane_basis

    centre = -plane.offset * plane.normal  # as in synth_run
    st = rng.uniform(-half_width_mm, half_width_mm, size=(n_points, 2))
    w = rng.normal(0.0, noise_mm, n_points)
    for e in effects:
        if e.name == "plane_form":
            w = w + _component(e, None).height(st)
    return centre + st @ plane_basis(plane.normal) + w[:, None] * plane.normal
