"""The head's turn from a commanded pose off the CAD's normal (metrology/measure/commanded.py)."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation


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
    from metrology.measure.beyond import convention_spin
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
    from metrology.measure.beyond import convention_spin
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
