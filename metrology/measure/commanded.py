"""The head's turn about its axis, from the robot's commanded pose, for a pose whose tool axis is off the
CAD's normal at the hole.

The cell's convention in closed form (``convention_spin``, what metro applied before; kept as the reference in
tests/measure/test_commanded.py) takes the head as its commanded pose ``R_c`` tilted onto the measured normal: the cell keeps its convention's spin at the head's actual axis (the
forward simulator's hole-table logs: commanded square to the CAD, the robot's attitude error
kept in the convention). It reads the actual axis in the commanded TCS as ``(m_x, m_y, -m_z)``,
which holds where the commanded axis is the CAD's normal (``R_c^T n = sigma e_z``). Where it is not
(a pose commanded off the normal: the forward simulator's logs of random holes, whose commanded pose
is the head itself, tilted 0.5-5 deg off the normal), that reading tilts the head a second time and
turns it about its axis by the holonomy of the two tilts, ``theta beta / 2`` (``theta`` the tilt off
the normal, ``beta`` the normal's angle to the panel's ``z``: 0.5 deg at 3 deg on a cylinder R 500 at
x = 200 mm), which turns a shape of unequal curvatures and its CAD beyond second order: on a
3-sensor head that measure-panel error is 0.002-0.005 deg, not in U95 (coverage 83 %,
benchmarks/results/study_extend_cylinder.md).

:func:`commanded_turn` is the same turn with the CAD's normal in the commanded TCS ``n_t`` taken as
it is: the head is ``R_c`` tilted by the smallest rotation taking the measured normal ``m`` onto
``n_t`` (``b = Q(m -> n_t) s e_z`` its axis in the commanded TCS), its spin the commanded one in the
cell's convention at that axis, ``Z = R_c^T Q(-e_z -> a) F F Q(-e_z -> f)^T R_c = Q(-r -> b)
Q(-r -> s e_z)^T``, and the shape, given square to the axis by ``Q_t = Q(n_t -> sigma e_z)``
(:meth:`metrology.measure.panel.HoleSurfaces.shape_pose`), turned by ``Y = Q_t Z Q_m``. Where
``n_t = sigma e_z`` it is ``convention_spin``'s ``Y``; where the head is
its commanded pose (``m = n_t``) it is the identity.
"""

from __future__ import annotations

import numpy as np

from metrology.core.sym3 import smallest_rotation

__all__ = ["commanded_turn", "cad_normal_tcs"]


def _mul(P, Q):
    """``P Q`` of 3 x 3 matrices given entry by entry (``P[i][j]`` arrays or floats)."""
    return [[P[i][0] * Q[0][j] + P[i][1] * Q[1][j] + P[i][2] * Q[2][j] for j in range(3)] for i in range(3)]


def cad_normal_tcs(axes, s: float):
    """``(nx, ny, nz)`` (h,) arrays: the CAD's unit normal in the commanded TCS, ``e1 x e2`` of the local
    axes ``axes (h, 2, 3)`` (unit, TCS: :class:`metrology.measure.beyond.Beyond`), toward the head
    (``sigma n_z > 0``, ``sigma = -s``)."""
    a = np.asarray(axes, float)
    n = np.cross(a[:, 0], a[:, 1])
    with np.errstate(invalid="ignore", divide="ignore"):
        n = n / np.linalg.norm(n, axis=1)[:, None]
    n = np.where((-s * n[:, 2] < 0)[:, None], -n, n)
    return n[:, 0], n[:, 1], n[:, 2]


def commanded_turn(Rc, m, nt, s: float):
    """``Y[i][j]`` ((h,) arrays): the turn the shape square to the axis takes (module docstring).

    ``Rc[i][j]`` (h,) arrays, the commanded pose ``tcs2panel``; ``m = (mx, my, mz)`` the measured unit
    normal, TCS, toward the head; ``nt = (nx, ny, nz)`` the CAD's unit normal in the commanded TCS, toward
    the head (:func:`cad_normal_tcs`); ``s`` the drill axis's sign."""
    mx, my, mz = m
    nx, ny, nz = nt
    sg = -s
    # D = Q(m -> n_t); b = D s e_z, the actual axis in the commanded TCS
    D = smallest_rotation(my * nz - mz * ny, mz * nx - mx * nz, mx * ny - my * nx, mx * nx + my * ny + mz * nz)
    bx, by, bz = s * D[0][2], s * D[1][2], s * D[2][2]
    rx, ry, rz = Rc[2][0], Rc[2][1], Rc[2][2]  # r = R_c^T e_z, the panel's z in the commanded TCS
    A = smallest_rotation(rz * by - ry * bz, rx * bz - rz * bx, ry * bx - rx * by, -(rx * bx + ry * by + rz * bz))
    B = smallest_rotation(-s * ry, s * rx, 0.0, -s * rz)  # Q(-r -> s e_z)
    Z = [[A[i][0] * B[j][0] + A[i][1] * B[j][1] + A[i][2] * B[j][2] for j in range(3)] for i in range(3)]  # A B^T
    Qt = smallest_rotation(sg * ny, -sg * nx, 0.0, sg * nz)  # Q(n_t -> sg e_z): k = n_t x sg e_z
    Qm = smallest_rotation(-sg * my, sg * mx, 0.0, sg * mz)  # Q(sg e_z -> m)
    return _mul(_mul(Qt, Z), Qm)
