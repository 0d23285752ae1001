"""Families of causes: what each one is physically, how big it is, and how a random member is drawn.

Every family draws a random *shape* within the family and is scaled to a *size* whose meaning and
unit are stated in :data:`FAMILIES`. Catalogued families are those ``metro diagnose`` may name;
``periodic`` and ``crosstalk`` are outside the catalogue (for honesty tests: they must come out
``unexplained``, never as a catalogued cause).

The effects act on a :class:`Scene` (true distances, incidence angles, times, temperatures, the
true poses): an effect returns the reading offsets it adds ``(p, n)`` mm, or new reported poses.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from metrology.sim.forward.characteristic import draw_curve
from metrology.sim.forward.drift import draw_drift
from metrology.sim.forward.errors import crosstalk_offset, periodic_offset
from metrology.sim.forward.incidence import draw_incidence
from metrology.sim.forward.poses import perturb_poses

__all__ = ["FamilySpec", "FAMILIES", "CATALOGUE", "OUT_OF_CATALOGUE", "Effect", "Scene", "draw_effect",
           "POSE_LEVER_MM"]

#: lever (mm) that converts a pose's orientation error to a spot displacement in the pose_error size
POSE_LEVER_MM = 50.0


@dataclass(frozen=True)
class FamilySpec:
    """How a family's size is defined: ``size_range`` (lo, hi) drawn uniformly, its meaning and unit."""

    size_range: tuple
    meaning: str
    unit: str
    in_catalogue: bool = True
    per_sensor: bool = True


FAMILIES = {
    "none": FamilySpec((0.0, 0.0), "no effect", "mm", True, False),
    "pose_error": FamilySpec((0.02, 0.10), "per-pose rigid tracker error: sqrt(offset^2 + (angle x 50 mm)^2), "
                             "offset and angle the lengths of the position and rotation-vector errors", "mm", True, False),
    "scale": FamilySpec((0.02, 0.20), "peak-to-valley of the gain error g*d over the sensor range", "mm"),
    "nonlinearity": FamilySpec((0.02, 0.20), "peak-to-valley of the characteristic curve over the sensor range", "mm"),
    "drift": FamilySpec((0.02, 0.15), "peak-to-valley of the drift offset over the run", "mm"),
    "incidence": FamilySpec((0.02, 0.15), "|bias| at the largest incidence angle the sensor sees", "mm"),
    "plane_form": FamilySpec((0.05, 0.50), "peak-to-valley of the datum height field over its extent", "mm", True, False),
    "outliers": FamilySpec((2, 6), "number of gross readings, each 0.1-2 mm off", "readings"),
    "shift": FamilySpec((0.02, 0.06), "jump of one sensor's zero point along its beam at one pose (a knock), "
                        "kept to the run's end; the pose uniform over the middle 80 % of the run", "mm"),
    "periodic": FamilySpec((0.02, 0.10), "amplitude of a sine in the pose index or in time", "mm", False),
    "crosstalk": FamilySpec((0.02, 0.10), "peak-to-valley of the shift, in proportion to another sensor's distance", "mm", False),
    "outside": FamilySpec((1.5, 4.0), "a term of a kind outside the catalogue (shape: kind, variables), 1.5-4 times "
                          "its detectable size (metrology.sim.forward.outside)", "mm", False),
}
CATALOGUE = tuple(k for k, v in FAMILIES.items() if v.in_catalogue and k != "none")
#: the two older out-of-catalogue families :func:`draw_effect` draws (the kinds of ``outside`` are
#: drawn by :mod:`metrology.sim.forward.outside`)
OUT_OF_CATALOGUE = tuple(k for k, v in FAMILIES.items() if not v.in_catalogue and k != "outside")


@dataclass(frozen=True)
class Effect:
    """One cause present in a case (the truth).

    Attributes
    ----------
    family : str, a key of ``FAMILIES``
    sensors : tuple of str, the sensors it acts on (all of them for pose_error and plane_form)
    size : float, in ``unit`` (meaning as ``FAMILIES[family].meaning``)
    shape : dict, the random shape drawn within the family (JSON-ready)
    """

    family: str
    sensors: tuple
    size: float
    shape: dict = field(default_factory=dict)

    @property
    def spec(self) -> FamilySpec:
        return FAMILIES[self.family]

    def to_dict(self) -> dict:
        s = self.spec
        return {"family": self.family, "sensors": list(self.sensors), "size": float(self.size),
                "size_meaning": s.meaning, "size_unit": s.unit, "in_catalogue": s.in_catalogue,
                "shape": self.shape}


@dataclass(frozen=True)
class Scene:
    """What effects act on.

    Attributes
    ----------
    names : tuple of str, length n
    d_true : (p, n) float, mm, true distances
    incidence : (p, n) float, rad, true incidence angles
    time_s : (p,) float, s
    temp_c : (p,) float, deg C
    rot : (p, 3, 3) float, true tcs2tracker rotations
    trans : (p, 3) float, mm, true tcs2tracker translations
    range_mm : (2,) float, mm
    """

    names: tuple
    d_true: np.ndarray
    incidence: np.ndarray
    time_s: np.ndarray
    temp_c: np.ndarray
    rot: np.ndarray
    trans: np.ndarray
    range_mm: tuple


def _pick(rng, k, n):
    return sorted(int(i) for i in rng.choice(n, size=k, replace=False))


def draw_effect(rng: np.random.Generator, family: str, scene: Scene, size: float, sensor: int):
    """Draw one member of ``family`` with ``size`` acting on sensor index ``sensor``.

    Returns ``(effect, offsets (p, n) mm or None, poses (rot_rep, trans_rep) or None, gross count)``;
    ``plane_form`` and ``outliers`` act elsewhere (the datum, after the noise) and return neither.
    """
    p, n = scene.d_true.shape
    off = np.zeros((p, n))
    name = (scene.names[sensor],)
    if family == "pose_error":
        mode = ["both", "orientation", "position"][int(rng.choice(3, p=[0.5, 0.25, 0.25]))]
        phi = {"both": rng.uniform(0.1, 1.47), "orientation": np.pi / 2, "position": 0.0}[mode]
        offset_mm, angle_rad = size * np.cos(phi), size * np.sin(phi) / POSE_LEVER_MM
        R, T, omega, delta = perturb_poses(rng, scene.rot, scene.trans, angle_rad, offset_mm)
        shape = {"split": mode, "offset_mm": float(offset_mm), "angle_rad": float(angle_rad),
                 "omega_rad": omega.tolist(), "delta_mm": delta.tolist()}
        return Effect(family, tuple(scene.names), size, shape), None, (R, T), 0
    if family in ("scale", "nonlinearity"):
        shape_name = "gain" if family == "scale" else ("table", "s_curve", "tanh")[int(rng.integers(3))]
        curve = draw_curve(rng, shape_name, *scene.range_mm, size)
        off[:, sensor] = curve(scene.d_true[:, sensor])
        return Effect(family, name, size, curve.to_dict()), off, None, 0
    if family == "drift":
        dr = draw_drift(rng, scene.time_s, scene.temp_c, size)
        off[:, sensor] = dr.offset(scene.time_s, scene.temp_c)
        return Effect(family, name, size, dr.to_dict()), off, None, 0
    if family == "incidence":
        amax = float(np.nanmax(scene.incidence[:, sensor]))
        bias = draw_incidence(rng, amax, size)
        off[:, sensor] = bias(scene.incidence[:, sensor])
        return Effect(family, name, size, {**bias.to_dict(), "max_angle_rad": amax}), off, None, 0
    if family == "periodic":
        in_time = bool(rng.integers(2))
        x = scene.time_s if in_time else np.arange(p, dtype=float)
        period = float(rng.uniform(0.05, 0.2) * scene.time_s[-1]) if in_time else float(rng.uniform(4.0, 15.0))
        phase = float(rng.uniform(0, 2 * np.pi))
        off[:, sensor] = periodic_offset(x, size, period, phase)
        shape = {"variable": "time_s" if in_time else "pose_index", "period": period, "phase_rad": phase}
        return Effect(family, name, size, shape), off, None, 0
    if family == "crosstalk":
        src = int(rng.choice([k for k in range(n) if k != sensor]))
        ptp = float(np.ptp(scene.d_true[:, src]))
        coupling = float(rng.choice([-1.0, 1.0]) * size / ptp)
        off[:, sensor] = crosstalk_offset(scene.d_true[:, src], coupling)
        return Effect(family, name, size, {"source": scene.names[src], "coupling": coupling}), off, None, 0
    if family == "shift":
        # the sensor knocked between two poses: its zero point moves by ``delta`` along its beam,
        # which shortens every later distance by ``delta`` whatever the pose (d = (D - N.E) / (N.u))
        k = int(rng.integers(int(np.ceil(0.1 * p)), int(np.floor(0.9 * p)) + 1))
        delta = float(rng.choice([-1.0, 1.0]) * size)
        off[k:, sensor] = -delta
        return Effect(family, name, size, {"at_pose": k, "time_s": float(scene.time_s[k]), "zero_moved_mm": delta}), \
            off, None, 0
    if family == "outliers":
        count = int(round(size))
        return Effect(family, name, count, {"delta_mm": [0.1, 2.0]}), None, None, count
    raise ValueError(f"family must be one of {tuple(FAMILIES)}, got {family!r}")
