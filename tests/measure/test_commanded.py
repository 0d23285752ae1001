"""The head's turn from a commanded pose off the CAD's normal (metrology/measure/commanded.py)."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from metrology.core.sym3 import smallest_rotation


# the cell's convention at the measured axis for a pose square to the CAD, in closed form: what metro applied
# before metrology/measure/commanded.py (moved here from measure/beyond.py), the reference the general turn reduces to
def _spin_entries(Rc, mx, my, mz, s: float):
    """:func:`convention_spin` entry by entry: ``Rc[i][j]`` and ``mx, my, mz`` (h,) arrays; returns ``Y[i][j]``.

    ``Y = Q_m^T X Q_m = R_c^T Q(-e_z -> a) Q(-e_z -> f)^T R_c Q_m`` (``F F = I``, ``R = R_c Q_m^T``),
    and a smallest rotation turned is the smallest rotation between the turned vectors:
    ``R_c^T Q(v -> w) R_c = Q(R_c^T v -> R_c^T w)``, with ``R_c^T a = s Q_m^T e_z = (m_x, m_y, -m_z)``
    and ``R_c^T f = s e_z``: ``Y = Q(-r -> b) Q(-r -> s e_z)^T Q_m``, ``r = R_c^T e_z`` (the panel's
    ``z`` in the TCS: ``R_c``'s last row), ``b = (m_x, m_y, -m_z)``."""
    rx, ry, rz = Rc[2][0], Rc[2][1], Rc[2][2]
    bz = -mz
    # A = Q(-r -> b): k = -r x b, c = -r . b
    A = smallest_rotation(rz * my - ry * bz, rx * bz - rz * mx, ry * mx - rx * my, -(rx * mx + ry * my + rz * bz))
    # B = Q(-r -> s e_z): k = -s (r_y, -r_x, 0), c = -s r_z
    B = smallest_rotation(-s * ry, s * rx, 0.0, -s * rz)
    # Q_m = Q(sg e_z -> m), sg = -s: I + [v]x + [v]x^2 / (1 + sg m_z), v = sg e_z x m = (-sg m_y, sg m_x, 0)
    sg = -s
    Q = smallest_rotation(-sg * my, sg * mx, 0.0, sg * mz)
    M = [[A[i][0] * B[j][0] + A[i][1] * B[j][1] + A[i][2] * B[j][2] for j in range(3)] for i in range(3)]  # A B^T
    return [[M[i][0] * Q[0][j] + M[i][1] * Q[1][j] + M[i][2] * Q[2][j] for j in range(3)] for i in range(3)]


def convention_spin(tcs2panel, m, s: float):
    """``Y (h, 3, 3)``: the turn about the drill axis that puts the head's spin where the cell's
    convention has it at the head's measured axis.

    The fit turns the shape, given square to the axis under ``tcs2panel`` (``R_c``), onto the measured
    normal ``m`` (TCS, toward the head) by the smallest rotation ``Q_m`` (``sigma e_z -> m``): the head
    ``R = R_c Q_m^T``. The cell holds the commanded spin ``psi_c`` in its convention (metrology/sim/forward/log.py
    step 3; :func:`metrology.measure.panel.tcs2panel_nominal`): at the axis ``a = R s e_z`` its head is
    ``Q(-e_z -> a) F Rz(psi_c)``, not ``R``. The two differ by a spin about the axis, the holonomy of the
    tilt: ``theta beta / 2`` or so for a tilt ``theta`` off an axis ``beta`` from the panel's ``z``
    (0.3 deg at 5 and 7.6 deg, the nacelle's table), which turns a shape of unequal curvatures (a
    saddle: ``2 delta_psi / R``). ``Y = Q_m^T X Q_m`` with ``X = R^T Q(-e_z -> a) F Rz(psi_c)``; the
    shape square to the axis becomes ``Y^T K Y``.

    ``tcs2panel (h, 3, 3)``, ``m (h, 3)`` unit TCS, ``s`` the drill axis's sign. Entry by entry over
    the holes (:func:`_spin_entries`, the closed form of the products)."""
    Rc = np.asarray(tcs2panel, float)
    m = np.asarray(m, float)
    e = _spin_entries([[Rc[:, i, j] for j in range(3)] for i in range(3)], m[:, 0], m[:, 1], m[:, 2], s)
    Y = np.empty((len(m), 3, 3))
    for i in range(3):
        for j in range(3):
            Y[:, i, j] = e[i][j]
    return Y


def _poses(rng, h, s, off_rad):
    """Commanded poses in the cell's convention at CAD normals up to 30 deg off the panel's z, their axis
    tilted ``off_rad`` off the normal and spun; the CAD's normal in each pose's TCS."""
    from metrology.measure.panel import tcs2panel_nominal

    n = rng.normal(0.0, 0.3, (h, 3)) + [0.0, 0.0, 1.0]
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    Rc = tcs2panel_nominal(n, s) @ Rotation.from_rotvec(rng.normal(0.0, [off_rad, off_rad, 0.5], (h, 3))).as_matrix()
    nt = np.einsum("hji,hj->hi", Rc, n)  # R_c^T n: toward the head
    return Rc, nt


def _entries(Rc):
    return [[Rc[:, i, j] for j in range(3)] for i in range(3)]


def _matrix(e):
    return np.stack([np.stack(row, -1) for row in e], -2)


def test_a_pose_square_to_the_cad_gives_the_conventions_turn():
    from metrology.measure.commanded import commanded_turn

    rng = np.random.default_rng(60)
    for s in (1.0, -1.0):
        Rc, _ = _poses(rng, 2000, s, 0.02)
        g = rng.normal(0.0, 0.05, (2000, 2))
        m = s * np.column_stack([g, -np.ones(2000)])
        m /= np.linalg.norm(m, axis=1, keepdims=True)
        Y = _matrix(commanded_turn(_entries(Rc), tuple(m.T), (0.0, 0.0, -s), s))
        np.testing.assert_allclose(Y, convention_spin(Rc, m, s), rtol=0, atol=1e-14)


def test_a_head_at_its_commanded_pose_off_the_normal_is_not_turned():
    """The pose is the head (m = n_t), 3 deg off the CAD's normal at 30 deg to the panel's z: no turn, where
    the convention's reading turns it by their holonomy (about 0.5 deg)."""
    from metrology.measure.commanded import cad_normal_tcs, commanded_turn

    rng = np.random.default_rng(61)
    for s in (1.0, -1.0):
        Rc, nt = _poses(rng, 2000, s, np.radians(3.0))
        e1 = np.cross(nt, rng.normal(size=(2000, 3)))
        e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
        axes = np.stack([e1, np.cross(nt, e1)], 1)
        np.testing.assert_allclose(np.column_stack(cad_normal_tcs(axes, s)), nt, atol=1e-14)
        Y = _matrix(commanded_turn(_entries(Rc), tuple(nt.T), tuple(nt.T), s))
        np.testing.assert_allclose(Y, np.broadcast_to(np.eye(3), Y.shape), atol=1e-13)
        turn = np.degrees(np.abs(Rotation.from_matrix(convention_spin(Rc, nt, s)).as_rotvec()[:, 2]))
        assert np.max(turn) > 0.2  # what the square-pose reading did here


def test_measure_panel_on_a_cylinder_with_poses_off_the_normal_leaves_no_error_of_its_own():
    """The forward simulator's log of random holes on a cylinder R 500 (its commanded pose the head itself,
    0.5-5 deg off the normal), a 3-sensor head, readings noise-free and the layout exact: each hole's normal
    measured with the panel known. The convention's reading of the pose left 0.002 deg median (0.005 at
    x = +-200 mm), a quarter of U95, uncovered (benchmarks/results/study_extend_cylinder.md)."""
    from metrology.jobs.measure_panel import footprint_mm, panel_hole_surfaces
    from metrology.measure.holes import Settings, measure_batch
    from metrology.measure.panel import HoleTable
    from metrology.panel.mesh import Panel
    from metrology.sim.forward import LogSpec, draw_head, make_panel, simulate_log
    from metrology.sim.forward.log_write import log_table
    from tests.measure.panel_fixtures import panel_mesh

    head = draw_head(np.random.default_rng(82), 3, noise_mm=0.004)
    surface = make_panel("cylinder", 500.0)
    (ch,) = simulate_log(LogSpec(head.true, head.true, surface, noise_mm=1e-6, standoff_mm=45.0), 123, 300)
    table = log_table(ch)
    P = ch.drill_point
    surf = panel_hole_surfaces(Panel(panel_mesh(surface)), HoleTable(tuple(map(str, table.column("hole_id").to_pylist())),
                                                                   P, -surface.normal_at(P), "holes"),
                               footprint_mm(head.true), 0.5, 0.0, 0.0)
    cols = measure_batch(head.true, table, Settings(surfaces=surf)).columns
    n = np.column_stack([cols.column(f"normal_{k}").to_numpy(zero_copy_only=False) for k in "xyz"]).astype(float)
    err = np.degrees(np.arccos(np.clip(-np.einsum("hi,hi->h", n, ch.normal_tcs), -1.0, 1.0)))
    assert np.all(np.isfinite(err))
    assert np.median(err) < 3e-4, np.median(err)
    assert np.max(err[np.abs(P[:, 0]) > 150.0]) < 1e-3, np.max(err[np.abs(P[:, 0]) > 150.0])
