"""Blind cases: a head, poses over a datum, zero, one or two causes, and the truth.

``draw_case(rng, family)`` draws, in this order and all from ``rng``: the head (3 or 4 sensors,
drawing and true layouts), the reading noise (3-10 um), the pose count (40-150), the datum (flat,
or with form for ``plane_form``), the true poses (tilts up to ``tilt_max_deg`` from the datum
normal), time stamps and a non-monotonic-or-not temperature history, the effects, the noise,
0-2 PLC blanks, then gross readings. The export carries the *reported* poses (equal to the true
ones unless there is a ``pose_error``) and the readings; the cloud is the datum sampled with
10 um noise.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from metrology.core.frames import quaternion_from_matrix
from metrology.core.layout import SensorLayout
from metrology.io.export import TrackerExport
from metrology.sim.forward.drift import draw_temperature, draw_times
from metrology.sim.forward.errors import add_blanks, add_gross, add_noise
from metrology.sim.forward.families import FAMILIES, Effect, Scene, draw_effect
from metrology.sim.forward.head import Head, draw_head
from metrology.sim.forward.poses import draw_poses
from metrology.sim.forward.surface import DatumSurface, draw_surface, sample_cloud, sample_hand_scan

__all__ = ["Case", "draw_case", "draw_pair", "draw_cases", "draw_outside"]

_FORM_SHAPES = ("bow", "twist", "higher", "mixed")


@dataclass(frozen=True)
class Case:
    """One simulated run and its truth.

    Attributes
    ----------
    family : str, ``none``, a family, or ``a+b`` for a pair
    effects : tuple of Effect, the causes present (empty for ``none``)
    nominal, true : SensorLayout, mm, TCS: the drawing and the true layout
    export : TrackerExport, reported poses and readings (what a user's files hold)
    cloud : (m, 3) float, mm, tracker frame, the datum scan
    surface : DatumSurface, the true datum
    head : Head
    true_rot : (p, 3, 3) float; true_trans : (p, 3) float, mm, tracker frame: the true poses
    d_true : (p, n) float, mm, true distances (no effect, no noise)
    incidence : (p, n) float, rad, true incidence angles
    noise_mm : float, mm, 1 sigma reading noise
    temperature : dict, the temperature profile
    blanks : tuple of (pose index, sensor index), readings left empty
    tilt_max_rad : float, rad
    """

    family: str
    effects: tuple
    nominal: SensorLayout
    true: SensorLayout
    export: TrackerExport
    cloud: np.ndarray
    surface: DatumSurface
    head: Head
    true_rot: np.ndarray
    true_trans: np.ndarray
    d_true: np.ndarray
    incidence: np.ndarray
    noise_mm: float
    temperature: dict
    blanks: tuple
    tilt_max_rad: float

    @property
    def sensors(self) -> tuple:
        """Sensor names of every effect, in order, without repeats."""
        out = []
        for e in self.effects:
            out += [s for s in e.sensors if s not in out]
        return tuple(out)

    def truth_dict(self) -> dict:
        """The truth as JSON-ready data (what ``truth.json`` holds)."""
        return {
            "family": self.family, "effects": [e.to_dict() for e in self.effects],
            "sensors": list(self.sensors), "noise_mm": self.noise_mm, "n_poses": self.export.n_poses,
            "n_sensors": self.nominal.n, "tilt_max_deg": float(np.degrees(self.tilt_max_rad)),
            "temperature": self.temperature, "blanks": [list(b) for b in self.blanks],
            "datum": self.surface.to_dict(), "head": self.head.to_dict(),
            "true_layout": {"zero_mm": self.true.zero.tolist(), "direction": self.true.direction.tolist()},
        }

    def to_dict(self) -> dict:
        return self.truth_dict()


def _choose(rng, value, choices):
    return value if value is not None else choices[int(rng.integers(len(choices)))]


def _draw(rng, families, sizes, *, n_sensors, noise_mm, n_poses, tilt_max_deg, range_mm, n_cloud,
          cloud_noise_mm, blanks, scan="tracker", outside=None) -> Case:
    for f in families:
        if f not in FAMILIES:
            raise ValueError(f"family must be one of {tuple(FAMILIES)}, got {f!r}")
    families = [f for f in families if f != "none"]
    n_sensors = int(_choose(rng, n_sensors, (3, 4)))
    noise_mm = float(noise_mm) if noise_mm is not None else float(rng.uniform(0.003, 0.010))
    n_poses = int(n_poses) if n_poses is not None else int(rng.integers(40, 151))
    sizes = [float(s) if s is not None else float(rng.uniform(*FAMILIES[f].size_range)) for f, s in zip(families, sizes)]
    head = draw_head(rng, n_sensors, noise_mm=noise_mm, range_mm=range_mm)
    form = [(f, s) for f, s in zip(families, sizes) if f == "plane_form"]
    form_shape = _FORM_SHAPES[int(rng.integers(4))] if form else "flat"
    surface, form_truth = draw_surface(rng, form_mm=form[0][1] if form else 0.0, shape=form_shape)
    tilt = np.radians(tilt_max_deg)
    rot, trans, hits = draw_poses(rng, surface, head.true.zero, head.true.direction, n_poses,
                                  tilt_max_rad=tilt, range_mm=range_mm, z0_mm=head.z0_mm)
    t = draw_times(rng, n_poses)
    profile = draw_temperature(rng, float(t[-1]))
    temp = profile(t)
    scene = Scene(head.nominal.names, hits.d, hits.incidence, t, temp, rot, trans, tuple(range_mm))
    # distinct sensors for per-sensor effects (pairs on one family act on two sensors)
    order = [int(i) for i in rng.permutation(n_sensors)]
    d = hits.d.copy()
    rot_rep, trans_rep = rot, trans
    effects, gross = [], []
    for k, (f, s) in enumerate(zip(families, sizes)):
        if f == "plane_form":
            effects.append(Effect(f, head.nominal.names, s, form_truth))
            continue
        eff, off, poses, count = draw_effect(rng, f, scene, s, order[k % n_sensors])
        if off is not None:
            d = d + off
        if poses is not None:
            rot_rep, trans_rep = poses
        if count:
            gross.append((len(effects), count))
        effects.append(eff)
    noise_scale = None
    if outside is not None:  # (kind, factor): an effect outside the catalogue on the first sensor of ``order``
        from metrology.sim.forward.outside import draw_outside_effect

        normal_tcs = np.einsum("pji,j->pi", rot, surface.normal)
        s_, t_, _ = surface.plane_coords(hits.spot)
        eff, off, noise_scale = draw_outside_effect(
            rng, outside[0], sensor=order[0], names=head.nominal.names, d_true=hits.d, incidence=hits.incidence,
            time_s=t, temp_c=temp, rot=rot, spot_st=np.stack([s_, t_], axis=-1), normal_tcs=normal_tcs,
            noise_mm=noise_mm, range_mm=range_mm, factor=outside[1])
        d = d + off
        effects.append(eff)
    d = add_noise(rng, d, noise_mm if noise_scale is None else noise_mm * noise_scale)
    n_blank = int(_choose(rng, blanks, (0, 1, 2)))
    d, blank_cells = add_blanks(rng, d, n_blank)
    for idx, count in gross:
        d, hits_g = add_gross(rng, d, count)
        names = tuple(sorted({head.nominal.names[j] for _, j, _ in hits_g}, key=head.nominal.names.index))
        effects[idx] = replace(effects[idx], sensors=names,
                               shape={**effects[idx].shape, "cells": [[i, head.nominal.names[j], dl] for i, j, dl in hits_g]})
    export = TrackerExport(
        tuple(f"P{i + 1:03d}" for i in range(n_poses)), t, np.round(temp, 3), quaternion_from_matrix(rot_rep),
        trans_rep, head.nominal.names, d)
    if scan == "hand":  # a hand-held probe: 40-80 um noise, 400-1500 points, 1-3 % strays (sample_hand_scan)
        cloud, _ = sample_hand_scan(surface, rng)
    elif scan == "tracker":
        cloud = sample_cloud(surface, rng, n_cloud, cloud_noise_mm)
    else:
        raise ValueError(f"scan must be 'tracker' or 'hand', got {scan!r}")
    family = "+".join(families) if families else ("outside" if outside is not None else "none")
    return Case(family, tuple(effects), head.nominal, head.true, export, cloud, surface, head, rot, trans,
                hits.d, hits.incidence, noise_mm, profile.to_dict(), tuple(blank_cells), tilt)


def draw_case(rng: np.random.Generator, family: str, *, n_sensors: int | None = None, noise_mm: float | None = None,
              n_poses: int | None = None, size: float | None = None, tilt_max_deg: float = 14.0,
              range_mm=(30.0, 70.0), n_cloud: int = 2000, cloud_noise_mm: float = 0.010,
              blanks: int | None = None, scan: str = "tracker") -> Case:
    """A random case carrying one effect of ``family`` (or none).

    Parameters
    ----------
    rng : numpy.random.Generator, the only source of randomness
    family : str, a key of ``FAMILIES``
    n_sensors : 3 or 4 (default: drawn)
    noise_mm : float, mm, reading noise 1 sigma (default: uniform 0.003-0.010)
    n_poses : int (default: uniform 40-150)
    size : float, the effect's size in its family's unit (default: uniform in its ``size_range``)
    tilt_max_deg : float, deg, largest tilt of the tool axis from the datum normal
    range_mm : (2,) float, mm, sensor range
    blanks : int, number of PLC blanks (default: drawn 0-2)
    scan : ``"tracker"`` (``n_cloud`` points, ``cloud_noise_mm``, no strays) or ``"hand"`` (a
        hand-probe scan, :func:`~metrology.sim.forward.surface.sample_hand_scan`; drawn after
        everything else, so the readings are those of the same seed's ``"tracker"`` case)
    """
    return _draw(rng, [family], [size], n_sensors=n_sensors, noise_mm=noise_mm, n_poses=n_poses,
                 tilt_max_deg=tilt_max_deg, range_mm=range_mm, n_cloud=n_cloud, cloud_noise_mm=cloud_noise_mm,
                 blanks=blanks, scan=scan)


def draw_pair(rng: np.random.Generator, family_a: str, family_b: str, *, n_sensors: int | None = None,
              noise_mm: float | None = None, n_poses: int | None = None, sizes=(None, None),
              tilt_max_deg: float = 14.0, range_mm=(30.0, 70.0), n_cloud: int = 2000,
              cloud_noise_mm: float = 0.010, blanks: int | None = None, scan: str = "tracker") -> Case:
    """A random case carrying two causes at once (issue 15); per-sensor causes act on different
    sensors. Parameters as :func:`draw_case`, ``sizes`` one per family."""
    if family_a == family_b and not FAMILIES[family_a].per_sensor:
        raise ValueError(f"a pair of {family_a!r} twice is one cause, give two families")
    if "none" in (family_a, family_b):
        raise ValueError("a pair needs two causes; use draw_case for one")
    return _draw(rng, [family_a, family_b], list(sizes), n_sensors=n_sensors, noise_mm=noise_mm, n_poses=n_poses,
                 tilt_max_deg=tilt_max_deg, range_mm=range_mm, n_cloud=n_cloud, cloud_noise_mm=cloud_noise_mm,
                 blanks=blanks, scan=scan)


def draw_outside(rng: np.random.Generator, kind: str, *, factor: float | None = None, n_sensors: int | None = None,
                 noise_mm: float | None = None, n_poses: int | None = None, tilt_max_deg: float = 14.0,
                 range_mm=(30.0, 70.0), n_cloud: int = 2000, cloud_noise_mm: float = 0.010,
                 blanks: int | None = None, scan: str = "tracker") -> Case:
    """A random case carrying one effect outside the catalogue, of ``kind`` (a key of
    :data:`~metrology.sim.forward.outside.OUTSIDE_KINDS`), ``factor`` times its detectable size
    (drawn in 1.5-4 when None); the rest as :func:`draw_case` (30-150 poses when ``n_poses`` is None)."""
    if n_poses is None:
        n_poses = int(rng.integers(30, 151))
    return _draw(rng, [], [], n_sensors=n_sensors, noise_mm=noise_mm, n_poses=n_poses, tilt_max_deg=tilt_max_deg,
                 range_mm=range_mm, n_cloud=n_cloud, cloud_noise_mm=cloud_noise_mm, blanks=blanks, scan=scan,
                 outside=(kind, factor))


def draw_cases(rng: np.random.Generator, family: str, count: int, **kw) -> list:
    """``count`` independent cases of ``family`` (each drawn from its own child generator)."""
    return [draw_case(child, family, **kw) for child in rng.spawn(count)]
