"""Simulated poses, datum points and readings: the building blocks of paper section 5.

The paper does not give its pose distribution. metro's default is a physical one:

* the tool axis points at the datum, tilted from its normal by an angle drawn uniformly
  in ``[0, tilt_max]`` (default 5 deg) about a uniformly random horizontal axis, with a
  uniformly random spin about the tool axis;
* the *stand-off* is the reading the sensors would give, on average, on a plane normal
  to the tool axis: drawn uniformly in ``standoff_mm`` (default 40-60 mm, the range of a
  typical 50 mm triangulation sensor);
* the drilling point (where the tool axis meets the datum) is spread uniformly over a
  square of side ``spread_mm`` (default 200 mm) around the datum's centre.

Every function takes an explicit ``numpy.random.Generator``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from metrology.core.frames import plane_in_tcs
from metrology.core.plane import plane_basis
from metrology.core.layout import SensorLayout
from metrology.core.model import readings

__all__ = ["PoseSpec", "Poses", "random_poses", "simulate_readings", "datum_points"]


@dataclass(frozen=True)
class PoseSpec:
    """The pose distribution (see the module docstring). Angles in rad, lengths in mm."""

    standoff_mm: tuple = (40.0, 60.0)
    tilt_max: float = np.deg2rad(5.0)
    spread_mm: float = 200.0
    spin: bool = True


@dataclass(frozen=True)
class Poses:
    """Poses of the TCS in the tracker frame.

    Attributes
    ----------
    tcs2tracker_rot : (p, 3, 3) float
    tcs2tracker_trans : (p, 3) float, mm, tracker frame
    """

    tcs2tracker_rot: np.ndarray
    tcs2tracker_trans: np.ndarray

    def plane_in_tcs(self, normal_tracker, offset_tracker):
        """The tracker-frame plane in each pose's TCS: ``(p, 3)`` normals, ``(p,)`` offsets mm."""
        return plane_in_tcs(normal_tracker, offset_tracker, self.tcs2tracker_rot, self.tcs2tracker_trans)


def _axis_height(layout: SensorLayout, reading_mm: float, axis_sign: float) -> float:
    """Distance along the tool axis from the TCS origin to a perpendicular plane at which
    the sensors' mean reading is ``reading_mm``."""
    z = layout.zero[:, 2] * axis_sign
    c = layout.direction[:, 2] * axis_sign
    # reading of sensor i on the plane {axis coordinate = h}: (h - z_i) / c_i
    return (reading_mm + np.mean(z / c)) / np.mean(1.0 / c)


def random_poses(rng: np.random.Generator, layout: SensorLayout, normal, offset, n_poses: int,
                 spec: PoseSpec = PoseSpec(), centre=None) -> Poses:
    """Random poses that put the sensors' spots on the plane ``normal . p + offset = 0``.

    Parameters
    ----------
    rng : numpy.random.Generator
    layout : SensorLayout
        Its mean beam direction defines which way the tool axis (TCS z) faces the datum.
    normal : (3,) float, unit, tracker frame
    offset : float, mm
    n_poses : int
    spec : PoseSpec
    centre : (3,) float, mm, tracker frame, optional
        Centre of the drilling-point spread (default: the foot of the perpendicular from
        the origin).

    Returns
    -------
    Poses
    """
    from scipy.spatial.transform import Rotation

    n = np.asarray(normal, float) / np.linalg.norm(normal)
    axis_sign = 1.0 if np.mean(layout.direction[:, 2]) > 0 else -1.0
    if np.min(layout.direction[:, 2] * axis_sign) <= 0.1:
        raise ValueError("every beam must point within 84 deg of the tool axis for these poses")
    centre = -offset * n if centre is None else np.asarray(centre, float)
    basis = plane_basis(n)
    # R0 maps the beam side of the tool axis (axis_sign * e_z) onto -n: beams go into the plane
    target = -n
    src = np.array([0.0, 0.0, axis_sign])
    # the shortest rotation taking src onto target, written out: scipy's align_vectors of one
    # vector pair returned another rotation (any spin about target) before scipy 1.12
    axis = np.cross(src, target)
    R0 = Rotation.from_rotvec(axis / max(np.linalg.norm(axis), 1e-300) * np.arctan2(np.linalg.norm(axis), src @ target)
                              if np.linalg.norm(axis) > 1e-12 else (np.zeros(3) if src @ target > 0 else np.array([np.pi, 0.0, 0.0])))
    rots, trans = [], []
    for _ in range(n_poses):
        spin = Rotation.from_rotvec([0.0, 0.0, rng.uniform(0, 2 * np.pi) if spec.spin else 0.0])
        tilt_axis = basis.T @ np.array([np.cos(a := rng.uniform(0, 2 * np.pi)), np.sin(a)])
        tilt = Rotation.from_rotvec(tilt_axis * rng.uniform(0.0, spec.tilt_max))
        R = (tilt * R0 * spin).as_matrix()
        reading = rng.uniform(*spec.standoff_mm)
        h = _axis_height(layout, reading, axis_sign)
        spot = centre + basis.T @ rng.uniform(-spec.spread_mm / 2, spec.spread_mm / 2, size=2)
        axis_tracker = R @ src  # beam-side tool axis in the tracker frame
        # the tool axis meets the datum at `spot`, a distance h from the TCS origin
        origin = spot - h * axis_tracker
        rots.append(R)
        trans.append(origin)
    return Poses(np.array(rots), np.array(trans))


def simulate_readings(rng: np.random.Generator, layout_true: SensorLayout, normal_tcs, offset_tcs,
                      noise_mm: float):
    """Readings of the true sensors on planes given in the TCS, with white Gaussian noise.

    Parameters
    ----------
    rng : numpy.random.Generator
    layout_true : SensorLayout
    normal_tcs : (p, 3) float, unit, TCS
    offset_tcs : (p,) float, mm
    noise_mm : float, mm, 1 sigma

    Returns
    -------
    d : (p, n) float, mm
    """
    d, valid = readings(layout_true.zero, layout_true.direction, normal_tcs, offset_tcs)
    if not np.all(valid):
        raise ValueError(f"{np.sum(~valid)} simulated beams miss the plane: check the pose distribution")
    return d + rng.normal(0.0, noise_mm, size=d.shape)


def datum_points(rng: np.random.Generator, normal, offset, n_points: int, noise_mm: float,
                 size_mm: float = 200.0, centre=None):
    """Points on a plane with isotropic Gaussian tracker noise (paper section 5 step 1).

    Parameters
    ----------
    normal : (3,) float, tracker frame; offset : float, mm
    n_points : int
    noise_mm : float, mm, 1 sigma per coordinate
    size_mm : float, mm, side of the square the points are drawn in
    centre : (3,) float, mm, optional (default: foot of the perpendicular from the origin)

    Returns
    -------
    points : (n_points, 3) float, mm, tracker frame
    """
    n = np.asarray(normal, float)
    scale = np.linalg.norm(n)
    n, offset = n / scale, offset / scale
    centre = -offset * n if centre is None else np.asarray(centre, float)
    uv = rng.uniform(-size_mm / 2, size_mm / 2, size=(n_points, 2))
    pts = centre + uv @ plane_basis(n)
    return pts + rng.normal(0.0, noise_mm, size=pts.shape)
