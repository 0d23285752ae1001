"""Tool poses over the datum, and rigid errors of the reported poses.

A pose is ``tcs2tracker``: ``p_tracker = R p_tcs + T`` (R (3, 3), T mm, tracker frame). Poses are
drawn with the TCS ``+z`` axis along ``-n`` (toward the datum), spun by a random angle about it
and tilted about a random axis perpendicular to ``n`` by an angle up to ``tilt_max`` (uniform
over the disc of tilt vectors); the TCS origin is put over a random point of the datum at a
stand-off that puts the readings inside the sensors' range. A pose is kept only when every beam
meets the datum's extent with a true distance inside the range shrunk by ``margin_mm``.

Pose error (the tracker's 6-DOF error): the *reported* pose differs from the *true* one by a
rigid perturbation per pose,

    R_rep = R_true Rot(omega),   T_rep = T_true + delta,

``omega`` (rad, TCS) a rotation vector of length ``angle_rad`` about a random axis, ``delta`` (mm,
tracker frame) of length ``offset_mm`` in a random direction. Readings come from the true pose;
the export carries the reported one.
"""

from __future__ import annotations

import numpy as np

from metrology.sim.forward.beams import cast_beams
from metrology.sim.forward.surface import DatumSurface

__all__ = ["draw_poses", "perturb_poses", "tilt_of"]


def _random_unit(rng, n):
    v = rng.normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def _candidates(rng, surface, n, tilt_max_rad, standoff_mm, fill):
    from scipy.spatial.transform import Rotation

    nrm = surface.normal
    spin = rng.uniform(0, 2 * np.pi, n)
    x0 = np.cos(spin)[:, None] * surface.axis_s + np.sin(spin)[:, None] * surface.axis_t
    z = np.broadcast_to(-nrm, (n, 3))
    y0 = np.cross(z, x0)
    R0 = np.stack([x0, y0, z], axis=2)  # columns: TCS axes in the tracker frame
    tilt = tilt_max_rad * np.sqrt(rng.uniform(0, 1, n))
    az = rng.uniform(0, 2 * np.pi, n)
    axis = np.cos(az)[:, None] * surface.axis_s + np.sin(az)[:, None] * surface.axis_t
    R = Rotation.from_rotvec(axis * tilt[:, None]).as_matrix() @ R0
    s = rng.uniform(-fill, fill, n) * surface.half_extent[0]
    t = rng.uniform(-fill, fill, n) * surface.half_extent[1]
    H = rng.uniform(*standoff_mm, size=n)
    T = surface.point(s, t) + H[:, None] * nrm
    return R, T


def draw_poses(rng: np.random.Generator, surface: DatumSurface, zero, direction, n_poses: int, *,
               tilt_max_rad: float, range_mm, z0_mm: float, margin_mm: float = 1.0, fill: float = 0.8):
    """``n_poses`` true poses whose beams all meet the datum inside the range.

    Parameters
    ----------
    zero : (n, 3) float, mm, TCS (the true layout)
    direction : (n, 3) float, TCS
    tilt_max_rad : float, rad, largest tilt of the tool axis from the datum normal
    range_mm : (2,) float, mm, the sensors' range
    z0_mm : float, mm, how far behind the TCS origin the zero points sit (sets the stand-off)

    Returns
    -------
    rot : (p, 3, 3) float; trans : (p, 3) float, mm, tracker frame; hits : BeamHits of the true poses
    """
    lo, hi = float(range_mm[0]), float(range_mm[1])
    cosb = float(np.mean(np.asarray(direction, float)[:, 2] / np.linalg.norm(direction, axis=1)))
    standoff = ((lo + 0.25 * (hi - lo)) * cosb - z0_mm, (hi - 0.25 * (hi - lo)) * cosb - z0_mm)
    Rs, Ts = [], []
    for _ in range(200):
        R, T = _candidates(rng, surface, max(2 * n_poses, 20), tilt_max_rad, standoff, fill)
        h = cast_beams(surface, zero, direction, R, T)
        ok = np.all(h.valid & (h.d >= lo + margin_mm) & (h.d <= hi - margin_mm), axis=1)
        Rs.append(R[ok])
        Ts.append(T[ok])
        if sum(len(r) for r in Rs) >= n_poses:
            break
    R = np.concatenate(Rs)[:n_poses]
    T = np.concatenate(Ts)[:n_poses]
    if len(R) < n_poses:
        raise ValueError(f"poses: only {len(R)} of {n_poses} poses keep every reading inside {range_mm} mm")
    return R, T, cast_beams(surface, zero, direction, R, T)


def perturb_poses(rng: np.random.Generator, rot, trans, angle_rad: float, offset_mm: float):
    """Reported poses: each true pose moved by a rigid perturbation (see the module docstring).

    Returns ``rot_rep (p, 3, 3)``, ``trans_rep (p, 3)`` mm, ``omega (p, 3)`` rad (TCS) and
    ``delta (p, 3)`` mm (tracker frame).
    """
    from scipy.spatial.transform import Rotation

    rot = np.asarray(rot, float)
    p = len(rot)
    omega = _random_unit(rng, p) * angle_rad
    delta = _random_unit(rng, p) * offset_mm
    return rot @ Rotation.from_rotvec(omega).as_matrix(), np.asarray(trans, float) + delta, omega, delta


def tilt_of(rot, surface: DatumSurface):
    """Angle (rad) between each pose's TCS ``+z`` axis and ``-normal`` of the datum; ``rot (p, 3, 3)``."""
    z = np.asarray(rot, float)[:, :, 2]
    c = np.clip(-(z @ surface.normal), -1.0, 1.0)
    return np.arccos(c)

